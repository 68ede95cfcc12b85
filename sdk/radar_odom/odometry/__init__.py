"""Radar odometry at run time: one sweep in, its pose and covariance out.

`RadarOdometer.step` (``odometer``) runs one sweep through these stages, each in its own module:

    check        time order, gaps, geometry, degenerate sweeps   odometer._check_time, sweep_checks, gaps.SweepPeriod
    graph input  the sweep as the graph takes it (de-skewed,     sweep_input.graph_input
                 or drawn in a predicted frame)
    predict      where the constant-velocity prior puts it       motion_prior.MotionPrior.predict,
                 (with ``centre_yaw``: the turn to draw it with)  gaps.compose_residual, centring.next_turn
    graph        the ONNX match against the reference's state    odometer._run_pair (radar_odom.onnx_model)
    fuse         the match with the prediction / external         motion_prior (information form, χ² gate)
                 odometry
    chain        the new absolute pose, the reference kept or    odometer._accept / _degenerate / _append
                 moved on

Offline forms of the same: ``pipeline`` (a recording read ahead on a worker thread while the graph
runs) and ``batch`` (many consecutive pairs per call of a sequence-form graph).
"""
