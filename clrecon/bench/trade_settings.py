"""The speed/accuracy trade's settings per method (:data:`TRADES`), apart from the report
that runs them (:mod:`clrecon.bench.trade`)."""
from __future__ import annotations

from typing import Any

#: per method, the settings that trade speed for accuracy (label, knobs); a method that is
#: not registered is skipped, a knob a method does not take is an error. ``safeguard=False``
#: is the paper's method alone; ``+safeguard`` the method's default
#: (:mod:`clrecon.methods.safeguard`); ``guided`` the method's halves refined by their box
#: images (:mod:`clrecon.methods.guided`), ``nlm`` the halves further averaged by dual-buffer
#: non-local means (:mod:`clrecon.methods.nlm`; with box: box's own halves)
TRADES: dict[str, tuple[tuple[str, dict[str, Any]], ...]] = {
    "box": (
        ("box", {}),
        # box's own halves through dual-buffer non-local means, blended toward box
        ("box nlm3 +safeguard", {"nlm": 3}),
        ("box nlm3x4 +safeguard", {"nlm": 3, "nlm_scales": 4}),
    ),
    "sweep": (
        ("sweep dof-layers", {"dof_layers": True, "safeguard": False}),
        ("sweep 2-scale", {"scales": 2, "safeguard": False}),
        ("sweep 2-scale ^1.3", {"scales": 2, "exponent": 1.3, "safeguard": False}),
        ("sweep 4-scale", {"scales": 4, "safeguard": False}),
        ("sweep 2-scale +safeguard", {"scales": 2}),
        ("sweep guided", {"scales": 2, "guided": 2, "safeguard": False}),
    ),
    "layered": (
        ("layered sheared", {"filter": "sheared", "safeguard": False}),
        ("layered mip", {"filter": "mip", "safeguard": False}),
        ("layered lrdm", {"mode": "lrdm", "safeguard": False}),
        ("layered full stats", {"stats_stride": 1, "safeguard": False}),
        ("layered no merging", {"merge_threshold": -1.0, "safeguard": False}),
        ("layered tile 16", {"tile": 16, "safeguard": False}),
        ("layered sheared +safeguard", {"filter": "sheared"}),
        ("layered guided", {"filter": "sheared", "guided": 2, "safeguard": False}),
        ("layered guided no blend", {"filter": "sheared", "guided": 2, "guide_blend": False,
                                     "safeguard": False}),
    ),
    "splat": (
        ("splat", {"safeguard": False}),
        ("splat mip 4", {"mip_radius": 4.0, "safeguard": False}),
        ("splat mip 12", {"mip_radius": 12.0, "safeguard": False}),
        ("splat 2 layers", {"layers": 2, "safeguard": False}),
        ("splat paper", {"mip_radius": 0, "safeguard": False}),
        ("splat paper f5", {"mip_radius": 0, "pyramid": "f5", "safeguard": False}),
        ("splat paper dense", {"dense": True, "safeguard": False}),
        ("splat +safeguard", {}),
        ("splat guided", {"guided": 2, "safeguard": False}),
        ("splat guided +safeguard", {"guided": 2}),
        ("splat guided nlm3", {"guided": 2, "nlm": 3, "safeguard": False}),
        ("splat guided nlm3 +safeguard", {"guided": 2, "nlm": 3}),
        ("splat guided nlm3x4", {"guided": 2, "nlm": 3, "nlm_scales": 4, "safeguard": False}),
        ("splat guided nlm3x4 +safeguard", {"guided": 2, "nlm": 3, "nlm_scales": 4}),
        ("splat guided nlm +safeguard", {"guided": 2, "nlm": 5}),
        # the chain and box's halves through the same filter, blended by their estimates
        ("splat guided nlm3x4 +hybrid", {"guided": 2, "nlm": 3, "nlm_scales": 4,
                                         "hybrid": True}),
    ),
}
