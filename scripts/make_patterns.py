"""Generate the bundled example patterns in static/patterns/ (deterministic; authored here).

    python scripts/make_patterns.py [--out static/patterns]

Writes
* ``sleeve_panels.dxf``: a DXF-AAMA / ASTM D6673 style pattern (millimetres, ``$INSUNITS`` = 4) of
  the sewn sleeve cut as two half panels, FRONT and BACK: each one BLOCK inserted once in
  modelspace, holding the boundary on layer 1 (a closed LWPOLYLINE, 125 x 80 mm: the two halves
  of configs/sewn_sleeve.yaml's 0.25 x 0.08 m panel, so that the two-panel sleeve can be checked
  against the one-panel one), the grainline on layer 7 (a LINE along x: the warp runs round the
  limb, as in sewn_sleeve.yaml), a notch at mid-length of each sewn side on layer 4, and the piece
  system text ``Piece Name: ...`` on layer 1.
* ``circle_blank.svg``: plain SVG text in millimetres (``width="200mm"`` over ``viewBox="0 0 200
  120"``): a circle of radius 50 mm (``id="circle_blank"``) with a horizontal grainline in its
  group, and a trapezoid polygon (``id="trapezoid"``: 80 mm wide at the bottom, 40 mm at the top,
  100 mm tall) with a vertical grainline.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import ezdxf

ROOT = Path(__file__).resolve().parents[1]

HALF_WIDTH_MM = 125.0               # half of sewn_sleeve.yaml's 0.25 m panel, round the limb [mm]
LENGTH_MM = 80.0                    # along the limb [mm]


def make_sleeve_panels(path: Path) -> None:
    """Write the AAMA-style two-panel sleeve (see the module docstring)."""
    doc = ezdxf.new("R2000", units=4)          # $INSUNITS = 4: millimetres
    doc.header["$MEASUREMENT"] = 1             # metric
    for layer in ("1", "4", "7"):
        doc.layers.add(layer)
    msp = doc.modelspace()
    w, h = HALF_WIDTH_MM, LENGTH_MM
    for k, name in enumerate(("FRONT", "BACK")):
        block = doc.blocks.new(name=name)
        block.add_lwpolyline([(0, 0), (w, 0), (w, h), (0, h)], close=True, dxfattribs={"layer": "1"})
        block.add_line((0.2 * w, 0.5 * h), (0.8 * w, 0.5 * h), dxfattribs={"layer": "7"})
        for x in (0.0, w):                     # notches at mid-length of both sewn sides
            inward = 5.0 if x == 0.0 else -5.0
            block.add_line((x, 0.5 * h), (x + inward, 0.5 * h), dxfattribs={"layer": "4"})
        block.add_text(f"Piece Name: {name}", dxfattribs={"layer": "1", "height": 5.0,
                                                           "insert": (10.0, 10.0)})
        block.add_text("Quantity: 1", dxfattribs={"layer": "1", "height": 5.0, "insert": (10.0, 20.0)})
        msp.add_blockref(name, (k * (w + 20.0), 0.0))
    path.parent.mkdir(parents=True, exist_ok=True)
    doc.saveas(path)


CIRCLE_BLANK_SVG = """<?xml version="1.0" encoding="UTF-8"?>
<!-- clothsim example pattern, authored by scripts/make_patterns.py. Units: millimetres
     (width 200mm over a 200-unit viewBox). Two pieces, each with a grainline in its group. -->
<svg xmlns="http://www.w3.org/2000/svg" width="200mm" height="120mm" viewBox="0 0 200 120">
  <g id="blank">
    <circle id="circle_blank" cx="60" cy="60" r="50" fill="none" stroke="black" stroke-width="0.3"/>
    <line id="blank_grain" class="grainline" x1="30" y1="60" x2="90" y2="60" stroke="blue" stroke-width="0.3"/>
  </g>
  <g id="trap">
    <polygon id="trapezoid" points="120,110 200,110 180,10 140,10" fill="none" stroke="black" stroke-width="0.3"/>
    <line id="trapezoid_grain" class="grainline" x1="160" y1="100" x2="160" y2="20" stroke="blue" stroke-width="0.3"/>
  </g>
</svg>
"""


def make_circle_blank(path: Path) -> None:
    """Write the plain-SVG circle blank and trapezoid (see the module docstring)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(CIRCLE_BLANK_SVG, encoding="utf-8")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "static" / "patterns")
    args = ap.parse_args(argv)
    make_sleeve_panels(args.out / "sleeve_panels.dxf")
    make_circle_blank(args.out / "circle_blank.svg")
    print(f"wrote {args.out / 'sleeve_panels.dxf'} and {args.out / 'circle_blank.svg'}")


if __name__ == "__main__":
    main()
