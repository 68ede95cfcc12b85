"""The de-skew stage of a stream: which twist each match's two sweeps are drawn with.

Motion compensation (``RadarOdometer(deskew=True)``; Cartesian models). A spinning radar takes a whole
period per sweep, so at 10 m/s the scene shifts 2.5 m between its first and last azimuth. With de-skew
on, each sweep is drawn as seen from the sensor at its first azimuth's instant (``scan.timestamp_us``),
every azimuth moved by the velocity of the motion so far (the mean of the last ``DESKEW_STEPS``
estimates, constant over the sweep, from each row's timestamp: Oxford and Boreas carry them, RADIATE's
are spread uniformly over the period; `radar_odom.polar.moving_sample_maps`). Poses then refer to the
first-azimuth instants of the two sweeps, so both sweeps of a match are drawn with the same twist.

`DeskewStage` holds what de-skew remembers of a stream beyond its reference (the last `DESKEW_STEPS`
estimates its velocity comes from, the redraws spent) and makes the twist decisions (docs/deskew.md); the
reference sweep and the twist it was drawn with are the stream's `Reference`, held once:

- the stream's twist (`DeskewStage.stream_twist`): the mean velocity of the last estimates, in the
  radar's frame (the model's mount yaw), or None where it would move no pixel;
- the pair's twist (`DeskewStage.pair_twist`): both sweeps of a match are drawn with one twist, the
  reference's, until the stream's has moved away from it (`sweep_input.twists_differ`): then the
  reference is redrawn with the stream's (one graph call, `MatchStage.draw_reference`);
- a stream's first match (`DeskewStage.first_match`): made as recorded, its pose over its interval
  gives the velocity, and the pair is drawn with it and matched again (``rematch``).

Twists are (vx m/s, vy m/s, yaw rate rad/s) in the radar's frame, as `sweep_input.deskew_twist` gives them;
velocities and poses come in the vehicle's frame.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Callable

import numpy as np

from ..scan import RadarScan
from ..se2 import turn_frame
from .sweep_input import deskew_twist, twists_differ

DESKEW_STEPS = 4  # estimates averaged into the de-skew velocity (1 s at 4 Hz)


class DeskewStage:
    """De-skew's state for one stream and its twist decisions.

    Args:
        enabled: de-skew on (already False for a model whose sweeps cannot be drawn moved); off, every
            twist is None and nothing is redrawn.
        profile: the model's `GridProfile` (which displacement moves a pixel).
        mount_yaw_rad: the model's mount yaw (``ModelInfo.mount_yaw_rad``): vehicle frame → radar's.
        drawer: what draws a reference again with a twist (`MatchStage`: ``draw_reference(scan, twist,
            turn)`` → the reference state, or None where the graph's output is not finite).
    """

    def __init__(self, enabled: bool, profile, mount_yaw_rad: float, drawer):
        self.enabled = bool(enabled)
        self.profile = profile
        self.mount_yaw_rad = mount_yaw_rad
        self._drawer = drawer
        self.recent_motion: deque = deque(maxlen=DESKEW_STEPS)  # (relative pose, interval s)
        self.reset()

    def reset(self) -> None:
        """Forget the stream (a new one starts)."""
        self.redraws = 0  # graph calls spent redrawing a reference for de-skew (this stream)
        self.recent_motion.clear()

    def forget_motion(self) -> None:
        """Forget how the stream moved (a new stream, or a new segment after a stamp jump)."""
        self.recent_motion.clear()

    def observe(self, relative_pose, interval_s: float) -> None:
        """An accepted (not gated) estimate: its pose (x m, y m, yaw rad; vehicle frame) over ``interval_s``."""
        self.recent_motion.append((np.asarray(relative_pose, dtype=np.float64), interval_s))

    def stream_twist(self, scan: RadarScan):
        """The velocity to de-skew ``scan`` with, or None: the mean over the last
        ``DESKEW_STEPS`` estimates (pose / interval). The last step alone feeds back: a yaw
        error de-skews the next sweep wrongly, which errs the next yaw the other way (measured
        on the shared RADIATE drive: per-step yaw error 1.58° with one step, 0.49° with four,
        0.48° without de-skew)."""
        if not self.enabled or not self.recent_motion:
            return None
        poses = np.array([m[0] for m in self.recent_motion])
        seconds = sum(m[1] for m in self.recent_motion)
        return self.radar_twist(poses.sum(axis=0) / seconds, scan)

    def radar_twist(self, velocity, scan: RadarScan):
        """`deskew_twist` of a velocity (x m/s, y m/s, yaw rad/s) in the vehicle's frame, the frame
        estimates are reported in: turned into the radar's by the model's mount yaw."""
        radar = turn_frame(np.asarray(velocity, dtype=np.float64), None, -self.mount_yaw_rad)[0]
        return deskew_twist(radar, scan, self.profile)

    def pair_twist(self, scan: RadarScan, ref):
        """The twist the new sweep is drawn with, the one the reference ``ref`` (a `Reference`) was drawn
        with: the stream's (`stream_twist`) once that has moved away from the reference's (the reference
        redrawn with it, one graph call), else the reference's; None with de-skew off."""
        if not self.enabled:
            return None
        want = self.stream_twist(scan)
        if ref.scan is None or not twists_differ(want, ref.twist, scan, self.profile):
            return ref.twist
        return want if self.redraw(ref, want) else ref.twist

    def first_match(self, scan: RadarScan, ref, interval_s: float, out, twist, rematch: Callable):
        """(match, twist) after the predict and match stages. A stream's first match with de-skew on
        (``twist`` None, no estimate yet): ``out``, made as recorded, gives the velocity over its
        ``interval_s``; the reference ``ref`` and the new sweep are drawn with it and matched again
        (``rematch(twist) -> match or None``, the odometer's match of the new sweep drawn with
        ``twist``; two graph calls in all). ``out`` and None where that velocity moves no pixel;
        (None, None) where the second match is not finite (the reference then stays redrawn).
        Any other step: ``(out, twist)`` as they are."""
        if out is None or twist is not None or not self.enabled or self.recent_motion:
            return out, twist
        twist = self.radar_twist(np.asarray(out.pose) / interval_s, scan)
        if twist is None or not self.redraw(ref, twist):
            return out, None
        again = rematch(twist)
        return (again, twist) if again is not None else (None, None)

    def redraw(self, ref, twist) -> bool:
        """Draw the reference sweep again with ``twist`` (in the turn it was drawn with) and make it the
        reference (one graph call, counted); False (the reference and its twist kept) where the graph's
        output is not finite."""
        feed = self._drawer.draw_reference(ref.scan, twist, ref.turn)
        self.redraws += 1
        if feed is None:
            return False
        ref.feed, ref.twist = feed, twist
        return True
