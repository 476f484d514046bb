"""CSV files a person opens in a spreadsheet: every writer of the package goes through these.

A spreadsheet runs a cell whose text starts with `=`, `+`, `-` or `@` as a formula (and a leading tab or carriage
return can hide such a start), so text that came from outside — a mode name, a reason, a log's boot id — could
call a function or a link when the file is opened (CSV injection, OWASP). Such text is written with a leading
single quote, which a spreadsheet shows as text and never runs. Numbers are written as they are: an int or
float, or a string that is a plain decimal number (`-0.25`, `1e-3`, as the figure writers format them), is not
touched.
"""

from __future__ import annotations

import csv
import re

FORMULA_START = ("=", "+", "-", "@", "\t", "\r")
_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")


def safe_cell(value):
    """`value` as a spreadsheet may show it without running it: text starting like a formula gets a leading `'`;
    anything else (numbers above all) is returned unchanged."""
    if isinstance(value, str) and value.startswith(FORMULA_START) and not _NUMBER.fullmatch(value):
        return "'" + value
    return value


class _SafeWriter:
    """`csv.writer` whose every cell passes `safe_cell`."""

    def __init__(self, fh, **kw):
        self._w = csv.writer(fh, **kw)

    def writerow(self, row):
        return self._w.writerow([safe_cell(v) for v in row])

    def writerows(self, rows):
        for row in rows:
            self.writerow(row)


def writer(fh, **kw) -> _SafeWriter:
    """A `csv.writer` on `fh` that neutralises formula-like text (`safe_cell`)."""
    return _SafeWriter(fh, **kw)


class DictWriter(csv.DictWriter):
    """`csv.DictWriter` that neutralises formula-like text in every cell (`safe_cell`), the header's too."""

    def writeheader(self):
        return self.writer.writerow([safe_cell(f) for f in self.fieldnames])

    def _dict_to_list(self, rowdict):
        return [safe_cell(v) for v in super()._dict_to_list(rowdict)]
