"""Numbers as people read them: fixed-precision text without a negative zero.

A value that rounds to zero at the printed precision prints as zero: a vented chamber at
-3e-6 MPa reads "Po 0.0000", not "Po -0.0000".
"""

from __future__ import annotations

import math


def fmt(value: float, spec: str) -> str:
    """`format(value, spec)`, with a result that reads as minus zero printed as zero.

    Works for the f, e, g and % presentation types with any width, sign and alignment.
    """
    text = format(value, spec)
    mantissa = text.lower().split("e")[0]
    if math.isfinite(value) and "-" in mantissa and not any(c in mantissa for c in "123456789"):
        return format(0.0, spec)
    return text
