"""The match stage: one call of the exported graph, whichever form it was exported in.

A stream-form graph takes (new sweep, reference state) and returns the pose, covariance and the new
sweep's state; a pair-form graph takes (reference sweep, new sweep); a sweep-form graph is a stream-form
one whose sweep input is the recorded sweep's arrays (a dict of feeds, `sweep_input.sweep_feeds`).
`GraphStep` hides the difference: the odometer keeps an opaque *reference* (a state or a sweep input)
and asks for a first reference and for matches against it.
"""
from __future__ import annotations

import numpy as np

from ..onnx_model import OnnxModel


class GraphStep:
    """The graph of an `OnnxModel` as two calls: `first` (a stream's reference) and `match`."""

    def __init__(self, model: OnnxModel):
        self.model = model
        self.info = model.info

    def first(self, x) -> np.ndarray:
        """The reference of a sweep with graph input ``x``: its state (stream form) or ``x`` (pair form).

        The stream graph has one signature, so the first state comes from a step against an
        all-zero state whose pose is discarded (one wasted correlation per stream).
        """
        if self.info.form == "pair":
            return x
        zero_state = np.zeros(self.info.state_shape, dtype=np.float32)
        return self.model.run(self._feeds(x, zero_state))["state"]

    def _feeds(self, x, state: np.ndarray) -> dict:
        """The stream graph's feeds: the sweep input (an array, or the sweep form's dict) and the state."""
        sweep = x if isinstance(x, dict) else {self.info.inputs[0]: x}
        return {**sweep, self.info.inputs[-1]: state}

    def match(self, x, reference: np.ndarray, keep_reference: bool = False):
        """(pose float64[3], covariance float64[3, 3] symmetrised, new reference) of the sweep with graph
        input ``x`` against ``reference``, or None where an output is not finite (``keep_reference``:
        the new reference is not wanted and not checked)."""
        if self.info.form == "pair":
            out = self.model.run({self.info.inputs[0]: reference, self.info.inputs[1]: x})
            new_ref = x
        else:
            out = self.model.run(self._feeds(x, reference))
            new_ref = out["state"]
        pose = np.asarray(out["pose"], dtype=np.float64).reshape(3)
        cov = np.asarray(out["covariance"], dtype=np.float64).reshape(3, 3)
        if not (np.all(np.isfinite(pose)) and np.all(np.isfinite(cov))):
            return None
        if not keep_reference and not np.all(np.isfinite(new_ref)):
            return None
        return pose, 0.5 * (cov + cov.T), new_ref
