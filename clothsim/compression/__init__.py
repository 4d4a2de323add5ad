"""Compression engineering: what a compression garment is specified, tested and prescribed by.

- :mod:`.spec`: the scene fields ``probes``, ``profiles`` and ``classes`` (pydantic; it imports only
  :mod:`.standards` and ``clothsim.strict``, so ``config`` can import it).
- :mod:`.standards`: compression classes (RAL-GZ 387, UK Drug Tariff) as data, and classifying.
- :mod:`.probes`: pressure sensors (discs on the mold) and profiles (slices along a limb's axis)
  read from an equilibrium; CSV and plot outputs.
- :mod:`.fit`: inverse sizing (``python app.py fit``): the value of a scene field that gives a
  target probe pressure.
- :mod:`.report`: one self-contained HTML report of a result folder (``python app.py report``),
  drawn by :mod:`.report_html`, :mod:`.report_figures` and :mod:`.report_levels` from what
  :mod:`.folder` puts in the folder (the body near the garment, the scene in short).

This package's ``__init__`` imports nothing heavy (the unit MMHG from :mod:`clothsim.units`):
``clothsim.config`` imports :mod:`.spec`.
"""

from ..units import MMHG  # noqa: E402,F401  (Pa per mmHg; defined once, in clothsim.units)
