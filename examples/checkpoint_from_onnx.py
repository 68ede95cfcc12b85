"""Recover a learned checkpoint from an exported model's masker weights (a warm start).

    python examples/checkpoint_from_onnx.py OLD.onnx cart-0.8 prev-cart-0.8.pt
    radar-odom train -o cart-0.8.pt --profile cart-0.8 --init-from prev-cart-0.8.pt ...

The exported graph keeps the U-Net's weights as initializers named ``…model.masker.<name>``;
they are loaded, strictly, into a fresh `MaskedCorrelator` of the given profile and saved as a
checkpoint (only the weights: the profile is the registry's, not the old file's). The shipped
models of this version were started this way from the previous release's (see README,
"How the shipped models were trained"): `git show c83f46e:sdk/radar_odom/models/cart-0.8.onnx`.
"""
import sys

import torch
from onnx import load, numpy_helper

from radar_odom.profiles import get_profile
from radar_odom_export.checkpoint import save_checkpoint
from radar_odom_export.model import MaskedCorrelator


def main(src: str, profile: str, out: str) -> None:
    graph = load(src).graph
    weights = {i.name.split("model.masker.", 1)[1]: torch.from_numpy(numpy_helper.to_array(i).copy())
               for i in graph.initializer if "model.masker." in i.name}
    model = MaskedCorrelator(get_profile(profile), masking="learned")
    model.masker.load_state_dict(weights, strict=True)
    save_checkpoint(out, model, "learned", train={"recovered_from_onnx": src.rsplit("/", 1)[-1]})
    print(f"wrote {out}: {len(weights)} masker tensors from {src}")


if __name__ == "__main__":
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    main(*sys.argv[1:])
