"""TOML files read with one line that says what is wrong: the standard library's ``tomllib`` (``tomli`` before
Python 3.11)."""
from __future__ import annotations

from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:     # Python 3.10
    import tomli as tomllib


def read_toml(path: Path, what: str) -> dict:
    """The tables of the TOML file ``path``, or ValueError naming ``what`` it is (``"rig file"``) and why it
    cannot be read."""
    try:
        return tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"{what} not found: {path}") from None
    except OSError as error:
        raise ValueError(f"{path}: cannot read the {what} ({error.strerror})") from None
    except tomllib.TOMLDecodeError as error:
        raise ValueError(f"{path}: not valid TOML ({error})") from None
