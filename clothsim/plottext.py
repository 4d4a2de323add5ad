"""Text from user data in matplotlib figures (scene, profile, probe and sweep names, swept values).

matplotlib parses a string with a pair of ``$`` as mathtext, and with ``text.usetex`` set in a
user's matplotlibrc hands every string to LaTeX: a scene named ``sleeve $20_$30`` made the profile
plot raise after the solve had converged. Every text drawn from user data therefore goes through
:data:`PLAIN` (keyword arguments of ``set_title``, ``set_xlabel``, ``set_xticklabels``, ...) or
:func:`plain_legend`, and is drawn as it is written. Numbers formatted by matplotlib itself (tick
labels of a log axis use mathtext on purpose) are left alone.
"""

from __future__ import annotations

#: Text properties that draw a string literally: no mathtext, no LaTeX
PLAIN = {"parse_math": False, "usetex": False}


def plain(text) -> None:
    """Make a matplotlib Text (or each of a list of them) draw its string literally."""
    for t in text if isinstance(text, (list, tuple)) else (text,):
        t.set_parse_math(False)
        t.set_usetex(False)


def plain_legend(ax, **kwargs):
    """``ax.legend(**kwargs)`` whose labels and title (user text) are drawn literally."""
    leg = ax.legend(**kwargs)
    plain(list(leg.get_texts()))
    plain(leg.get_title())
    return leg


def failure(exc: BaseException) -> str:
    """A one-line account of why a plot failed: the exception's type and the first line of its
    message (mathtext's messages start with a newline and run over several lines)."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    return f"{type(exc).__name__}: {lines[0][:160]}" if lines else type(exc).__name__
