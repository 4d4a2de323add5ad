"""The field checks every scene model shares: bounds on coordinates and densities, finite and
positive numbers, integers that refuse booleans, and the tags of the mold union's branches
(which :mod:`.sourcelines` drops from error locations)."""

from __future__ import annotations

import math
from typing import Annotated, Any, Union

from pydantic import BeforeValidator

from ..fileio import fmt_beyond
from ..strict import positive_finite


#: bound on every coordinate, length and displacement [m]: far beyond any garment or mold, and
#: small enough that squared distances and spring energies cannot overflow a float
COORD_MAX = 1e6
#: bound on gravity's areal density [kg/m^2] (a 1 m thick steel plate is 7850) and on g [m/s^2]
DENSITY_MAX = 1e4
G_MAX = 1e4
#: bound on a seam's stiffness [N/m^2]: 1000 x TENSION_MAX / a 1 mm grid spacing
SEAM_STIFFNESS_MAX = 1e15


def _finite(v, name="value"):
    if v is not None and not math.isfinite(v):
        raise ValueError(f"must be finite (got {v})")
    return v


def _positive(v, hi: float | None = None, unit: str = ""):
    """None, or a positive finite number (else the validation message every such field gives),
    at most ``hi`` if given."""
    if v is not None:
        positive_finite(v)
    if v is not None and hi is not None and v > hi:
        raise ValueError(f"at most {hi:.0e}{' ' + unit if unit else ''} (got {fmt_beyond(v, hi)})")
    return v


def _coords(v):
    """A coordinate, length or tuple of them [m], each finite with |x| <= COORD_MAX."""
    if v is None:
        return v
    for x in (v if isinstance(v, (tuple, list)) else [v]):
        _finite(x)
        if abs(x) > COORD_MAX:
            raise ValueError(f"|x| must be at most {COORD_MAX:.0e} m (got {fmt_beyond(x, COORD_MAX) if x > 0 else fmt_beyond(x, -COORD_MAX)})")
    return v


def _direction(v):
    if not all(math.isfinite(x) for x in v) or sum(x * x for x in v) == 0:
        raise ValueError(f"must be a non-zero finite vector (got {list(v)})")
    return v


def _strict_int(v):
    """Integers only: a YAML ``true`` is not 1; an integral float (2e5) is its integer."""
    if isinstance(v, bool):
        raise ValueError(f"must be an integer (got {str(v).lower()})")
    if isinstance(v, float):
        if not v.is_integer():
            raise ValueError(f"must be an integer (got {v})")
        return int(v)
    return v


#: an int field that refuses booleans (pydantic would take true as 1)
Int = Annotated[int, BeforeValidator(_strict_int)]


def _lattice_index(v):
    """A lattice index: an integer (negative counts from the end) or a share of the way across,
    ``"50%"`` (0 to 100 %; :func:`clothsim.selection.index_range` takes the nearest node), kept as
    the text ``"<p>%"``."""
    if isinstance(v, str):
        text = v.strip()
        try:
            share = float(text[:-1]) if text.endswith("%") else None
        except ValueError:
            share = None
        if share is None or not (0.0 <= share <= 100.0):
            raise ValueError(f"must be an integer or a share of the way across from 0% to 100%, such as "
                             f"'50%' (got {_short(v)})")
        return f"{int(share)}%" if share.is_integer() else f"{share!r}%"
    return _strict_int(v)


#: a lattice index field: an integer, or a share of the way across ("50%", the nearest node), so
#: that a selector keeps its place when the divisions change
LatticeIndex = Annotated[Union[int, str], BeforeValidator(_lattice_index)]


def _short(v: Any, n: int = 40) -> str:
    """repr of a user value, cut to n characters (error messages never echo a whole input)."""
    r = repr(v)
    return r if len(r) <= n else r[: n - 3] + "..."


def _finite3(v, what: str = "3 finite numbers"):
    if not all(math.isfinite(x) for x in v):
        raise ValueError(f"must be {what} (got {list(v)})")
    return v


def _nonzero3(v):
    _finite3(v, "a non-zero finite vector")
    if sum(x * x for x in v) == 0:
        raise ValueError(f"must be a non-zero finite vector (got {list(v)})")
    return v




MOLD_PRIMITIVES = ("sphere", "cylinder", "plane", "box", "leg")
# pydantic puts the union branch's tag into error locations; format_validation_error drops these
_MOLD_TAGS = tuple(f"mold:{k}" for k in ("mesh", *MOLD_PRIMITIVES))
