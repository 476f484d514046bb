"""The largest value of a sliding time window, in O(1) amortised per sample (a monotone queue). Pure."""

from __future__ import annotations

from collections import deque


class WindowMax:
    """`add(t, v)` a sample (times non-decreasing), then `max` is the largest `v` of those with
    `t_i >= t - window_s` (the sample just added always counts)."""

    def __init__(self, window_s: float):
        self.window_s = window_s
        self._q: deque[tuple[float, float]] = deque()  # (t, v), v decreasing: the front is the window's max

    def add(self, t: float, v: float) -> None:
        q = self._q
        while q and q[-1][1] <= v:
            q.pop()
        q.append((t, v))
        while q[0][0] < t - self.window_s:
            q.popleft()

    def value(self, t: float, empty: float = 0.0) -> float:
        """The largest value of the window ending at t (`empty` when it holds none)."""
        q = self._q
        while q and q[0][0] < t - self.window_s:
            q.popleft()
        return q[0][1] if q else empty

    @property
    def max(self) -> float | None:
        """The window's largest value (None before the first sample, or after `clear`)."""
        return self._q[0][1] if self._q else None

    def clear(self) -> None:
        self._q.clear()
