"""Material presets: tension per width [N/m] against engineering strain, warp (wale) and weft
(course) directions.

All presets are *estimates* for quick studies, not measurements of a specific product; import your
own strip-test data (EN 14704-1, KES-FB1, ASTM D4964) as CSV for real work. Sources of the shapes
and magnitudes (see docs/method/materials_data.md):

- J-shaped, tension-only curves; knits stretch more in the course (weft) direction than the wale
  (warp) direction, the wale 1.5-3 times stiffer (RMIT study, JFBI 4:1, 2011).
- powernet: course curve 0/0.1/0.3/0.6/1.0/1.5 -> 0/12/55/140/300/800 N/m, estimated from Laplace's
  law and EN 14704-1 cycling loads (4 N/cm for weft knits over 5 % elastane).
- compression garments: 20 mmHg on a 5 cm radius needs about 130 N/m (Ashby et al., Sports
  Engineering 2021 report 13-28 mmHg at the ankle for made-to-measure tights).
- elastic woven: stiffer, shorter curve; EN 14704-1 cycles wovens to 6 N/cm.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Preset:
    description: str
    strain: tuple[float, ...]
    warp: tuple[float, ...]  # N/m
    weft: tuple[float, ...]  # N/m


PRESETS: dict[str, Preset] = {
    "powernet_est": Preset(
        "Powernet / spandex warp knit (est.): course curve from the materials note, wale 2x stiffer",
        (0.0, 0.1, 0.3, 0.6, 1.0, 1.5),
        (0.0, 24.0, 110.0, 280.0, 600.0, 1600.0),
        (0.0, 12.0, 55.0, 140.0, 300.0, 800.0),
    ),
    "swimwear_knit_est": Preset(
        "Nylon/spandex single jersey, swimwear weight (est.): near-linear to 100 % strain, wale 1.5x",
        (0.0, 0.2, 0.5, 1.0, 1.5, 2.0),
        (0.0, 30.0, 80.0, 170.0, 330.0, 700.0),
        (0.0, 20.0, 55.0, 115.0, 220.0, 470.0),
    ),
    "compression_knit_est": Preset(
        "Medical/sports compression knit (est.): ~130 N/m at 30-40 % course strain (20 mmHg on r = 5 cm)",
        (0.0, 0.1, 0.2, 0.4, 0.7, 1.0),
        (0.0, 60.0, 140.0, 330.0, 700.0, 1300.0),
        (0.0, 30.0, 70.0, 160.0, 340.0, 650.0),
    ),
    "elastic_woven_est": Preset(
        "Stretch woven with elastane in the weft (est.): stiff warp, weft 6 N/cm near 25 % strain",
        (0.0, 0.05, 0.1, 0.2, 0.3, 0.4),
        (0.0, 300.0, 900.0, 2500.0, 5000.0, 9000.0),
        (0.0, 60.0, 150.0, 450.0, 1000.0, 2200.0),
    ),
    "isotropic_paper": Preset(
        "Isotropic J-curve (warp = weft) like the seed paper's examples; magnitudes estimated",
        (0.0, 0.1, 0.3, 0.6, 1.0),
        (0.0, 15.0, 60.0, 160.0, 400.0),
        (0.0, 15.0, 60.0, 160.0, 400.0),
    ),
}
