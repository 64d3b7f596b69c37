"""The small texts a scene's properties hold: a name and its numbers (``"cauchy 2.5e6"``, ``"hwp 22.5"``)."""
from __future__ import annotations

import math


def name_and_numbers(text: str, what: str) -> tuple[str, list[float]]:
    """``text``'s first word and the finite numbers after it; ``what`` names the text in the errors."""
    words = text.split()
    if not words:
        raise ValueError(f"{what} is empty: give a name and its numbers")
    name, *numbers = words
    try:
        values = [float(x) for x in numbers]
    except ValueError:
        raise ValueError(f"{what} '{text.strip()}': give numbers after '{name}', got {numbers}") from None
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{what} '{text.strip()}': the numbers must be finite")
    return name, values
