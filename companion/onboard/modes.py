"""The daemon's modes (config `mode`) as objects: what each one flies, commands and answers for. The call sites ask
a mode's attributes, never its name; a new mode is a new class here, the config's `Literal` and the docs."""
from __future__ import annotations


class Mode:
    """One daemon mode: its name (the config's and the logs' string) and what it decides. By default a mode flies
    under the stop contract, commands the autopilot, and neither governs its mission nor flies a route."""

    name: str
    contract = "stop"  # the contract it flies under: "stop" | "avoid"
    commands = True  # it commands the autopilot (Hold, a speed, setpoints); False: it computes and logs only
    governs = False  # the autopilot flies its mission under the daemon's speed limit and Hold
    flies_route = False  # the daemon flies the route itself (setpoints round the keep-out discs)
    resumes: str  # how a flight held for no safe speed resumes once `{needs}` holds
    resume_short = ""  # the same in a few ASCII words (STATUSTEXT); "" for nothing to do

    def resume(self, needs: str) -> str:
        """How a flight held for no safe speed resumes once `needs` holds."""
        return self.resumes.format(needs=needs)

    def __str__(self) -> str:
        return self.name


class Shadow(Mode):
    """Computes and logs what a governor would do; commands nothing."""

    name, commands = "shadow", False
    resumes = "no speed until {needs} (a governor would keep its Hold until the mode is changed)"


class Governor(Mode):
    """The autopilot flies its mission; the daemon limits its speed and commands Hold (the stop contract)."""

    name, governs = "governor", True
    resume_short = "change mode"
    resumes = ("once {needs}, change the flight mode (e.g. back to the mission): the daemon keeps its Hold "
               "until the pilot or a ground station does (not before: until then no speed is safe)")


class Offboard(Mode):
    """The daemon flies the route itself under the avoid contract."""

    name, contract, flies_route = "offboard", "avoid", True
    resume_short = "CG_ENGAGE 0, 1"
    resumes = ("once {needs}, set CG_ENGAGE 0 then 1 to fly the route again, or change the flight mode "
               "(the fail-safe Hold is kept until then)")


MODES: dict[str, Mode] = {m.name: m for m in (Shadow(), Governor(), Offboard())}


def mode_of(mode: str | Mode) -> Mode:
    """The mode object for a config's string (a mode object is returned as it is)."""
    return mode if isinstance(mode, Mode) else MODES[mode]
