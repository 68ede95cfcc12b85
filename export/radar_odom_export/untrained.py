"""Export an untrained learned-mask model of a grid profile, for timing only.

``radar-odom profile`` runs this in a child interpreter (``python -m radar_odom_export.untrained
PROFILE OUT.onnx fast|exhaustive|decoupled``) when a profile has no trained model, so that the profiling
process never imports torch and its memory figures stay honest. Weights do not change the time.
"""
from __future__ import annotations

import sys

SEARCHES = ("fast", "exhaustive", "decoupled")


def export_untrained(profile_name: str, path, search: str = "fast") -> None:
    """Seeded, untrained `MaskedCorrelator` of ``profile_name`` exported to ``path``."""
    import torch

    from radar_odom.profiles import get_profile

    from .model import MaskedCorrelator
    from .onnx_export import export_decoupled, export_fast, export_model

    if search not in SEARCHES:
        raise ValueError(f"search must be one of {SEARCHES}, got {search!r}")
    torch.manual_seed(0)
    model = MaskedCorrelator(get_profile(profile_name), masking="learned").eval()
    export = {"fast": export_fast, "decoupled": export_decoupled, "exhaustive": export_model}[search]
    export(model, path, verify=False, training_data="untrained (radar-odom profile)")


def main(argv=None) -> int:
    args = sys.argv[1:] if argv is None else list(argv)
    if len(args) != 3:
        print("usage: python -m radar_odom_export.untrained PROFILE OUT.onnx fast|exhaustive|decoupled",
              file=sys.stderr)
        return 2
    export_untrained(*args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
