"""Yaw centring: each sweep drawn turned by the yaw the motion prior predicts, one graph call per sweep.

Every matcher pulls a match toward the candidate at which the two images' pixel grids coincide
(texture fixed to the grid: range bins far finer than a pixel, the masker's pooling phase; see
docs/yaw-precision.md). Drawn in its own sensor frame, each sweep puts that candidate at "no
rotation", so turns are read short and the yaw lost on a bend never comes back. Drawing the new
sweep turned by the predicted yaw moves that candidate to the prediction: a steady turn is read
whole, a change of turn rate is read late by the same fraction on the way in and on the way out,
so the heading over a whole bend is not lost.

The frames: a sweep drawn with ``frame_pose = (0, 0, a)`` is the scene as seen from its sensor
frame turned by ``a`` (D = S·R(a)). The graph measures the pose Q of the new drawn frame in the
reference's drawn frame, Q = R(−a_ref)·T·R(a_new), so the sweep's pose in the reference's sensor
frame is T = R(a_ref)·Q·R(−a_new). The reference keeps the turn it was drawn with (a stream-form
graph's state is the drawn sweep's features), so turns accumulate: ``a_new = a_ref − ŷ`` puts the
predicted residual yaw at 0 with one graph call per sweep. Only the translation search window turns
with ``a`` (the ±window is square, so it reaches as far), and a turn beyond ``max_turn_rad`` re-draws
the reference once in its own frame (a second call) so the masker sees sweeps near the orientation
it was trained on.
"""
from __future__ import annotations

import math

import numpy as np

from ..se2 import turn_frame, wrap_angle

# Turns of the drawn frame up to this are kept from sweep to sweep; beyond it the reference is
# re-drawn in its sensor frame (one extra graph call, rare: every ~10° of heading change).
MAX_TURN_RAD = math.radians(10.0)


def next_turn(ref_turn_rad: float, predicted_yaw_rad: float | None) -> float:
    """The turn ``a_new`` (rad) to draw the new sweep with: ``a_ref − ŷ``, so the graph's residual
    yaw is 0 where the prediction holds (``ŷ`` None: no prediction yet, the reference's turn kept)."""
    if predicted_yaw_rad is None or not math.isfinite(predicted_yaw_rad):
        return float(ref_turn_rad)
    return float(wrap_angle(float(ref_turn_rad) - float(predicted_yaw_rad)))


def uncentre(residual, residual_cov, ref_turn_rad: float, new_turn_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """(pose float64[3], covariance float64[3, 3]) of the new sweep in the reference's sensor frame.

    Args:
        residual: float[3] (x m, y m, yaw rad) Q: the graph's pose of the new drawn frame in the
            reference's drawn frame.
        residual_cov: float[3, 3] its covariance (in the reference's drawn frame).
        ref_turn_rad: ``a_ref``, the turn the reference sweep was drawn with.
        new_turn_rad: ``a_new``, the turn the new sweep was drawn with.

    Returns T = R(a_ref)·Q·R(−a_new): translation turned by ``a_ref``, yaw ``yaw_Q + a_ref − a_new``
    (wrapped), the covariance turned with the translation (the turns are exact, not uncertain).
    """
    pose, cov = turn_frame(np.asarray(residual, dtype=np.float64).reshape(3),
                           np.asarray(residual_cov, dtype=np.float64).reshape(3, 3), float(ref_turn_rad))
    pose[2] = float(wrap_angle(pose[2] + float(ref_turn_rad) - float(new_turn_rad)))
    return pose, 0.5 * (cov + cov.T)
