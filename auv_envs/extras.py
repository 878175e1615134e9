"""Optional dependencies (``pyproject.toml``'s extras) and the one-line error a missing one
gives: :class:`MissingExtra` names the extra to install, and the command-line programs
print it as one line (:func:`one_line_errors`), without a traceback."""

from __future__ import annotations

import contextlib
import importlib
import sys
from types import ModuleType


class MissingExtra(ImportError):
    """An optional dependency is not installed: ``what`` needs ``extra``."""

    def __init__(self, what: str, extra: str, note: str = ""):
        self.extra = extra
        super().__init__(f"{what} needs the {extra!r} extra: pip install -e \".[{extra}]\" "
                         f"(or pip install \"auv_envs[{extra}]\"){note}")


def require(module: str, extra: str, what: str, note: str = "") -> ModuleType:
    """``module`` imported, or :class:`MissingExtra` (with no chained traceback) when it or
    one of its own dependencies is missing."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise MissingExtra(what, extra, note) from None


@contextlib.contextmanager
def one_line_errors(prog: str):
    """A command line's body: a :class:`MissingExtra` inside it is printed as one line,
    ``<prog>: error: <message>``, and exits with status 2 (as argparse's errors do)."""
    try:
        yield
    except MissingExtra as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
