"""Radar odometry at run time: one sweep in, its pose and covariance out.

`RadarOdometer.step` (``odometer``: the stream's state and the order of the stages, ``_step``) runs one
sweep through these stages, each in its own module:

    time         in order, the same range bins, a new segment   stream_time, gaps.SweepPeriod (the period:
                 after a stamp jump, the interval's gap flag     io.timebase, fitted once per recording)
    sweep checks geometry, degenerate sweeps                     sweep_checks
    graph input  the sweep as the graph takes it (de-skewed      sweep_input.graph_input, polar
                 with the reference's twist, or drawn in a
                 predicted frame)
    predict      where the constant-velocity prior puts it       motion_prior.MotionPrior.predict,
                 (across a gap: an arc; with ``centre_yaw``:      gaps.crossing_prior, centring.next_turn
                 the turn to draw it with)
    match        the ONNX graph against the reference; a gap     graph_step.GraphStep,
                 from several window centres, taken where         gaps.crossing_readings / consensus
                 readings agree within the gap's prior
    fuse         the match with the prediction / external        motion_prior (information form, χ² gate)
                 odometry
    chain        the new absolute pose, the reference kept or    odometer._accept / _degenerate / _append;
                 moved on                                        estimate (Estimate, Trajectory)

Offline forms of the same: ``pipeline`` (a recording read ahead on a worker thread while the graph
runs) and ``batch`` (many consecutive pairs per call of a sequence-form graph).
"""
