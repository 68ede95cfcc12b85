"""Radar odometry at run time: one sweep in, its pose and covariance out.

`RadarOdometer.step` (``odometer``: the stream's state and the order of the stages, ``_step``) runs one
sweep through these stages, each in its own module:

    time         in order, the same range bins, a new segment   stream_time (StreamClock: the stamps'
                 after a stamp jump; the periods the stamps      count of periods, advice only; the
                 put in the interval                             match decides, match_stage)
    sweep checks geometry, degenerate sweeps                     sweep_checks
    graph input  the sweep as the graph takes it (de-skewed      sweep_input.graph_input, polar;
                 with the reference's twist, or drawn in a       deskew_stage.DeskewStage (which twist,
                 predicted frame)                                when the reference is redrawn)
    predict      where the constant-velocity prior puts it       match_stage.MatchStage (which match),
                 (across a gap: an arc; with ``centre_yaw``:      motion_prior.MotionPrior.predict,
                 the turn to draw it with)                       gaps.crossing_prior, centring.next_turn
    match        the ONNX graph against the reference; a gap     match_stage.MatchStage.match,
                 from several window centres, taken where         graph_step.GraphStep,
                 readings agree within the gap's prior;          gaps.crossing_readings / consensus;
                 de-skew's first match drawn again with the      deskew_stage.DeskewStage.first_match
                 velocity it measured
    fuse         the match with the prediction / external        motion_prior (information form, χ² gate)
                 odometry
    chain        the new absolute pose, the reference kept or    odometer._accept / _degenerate / _append;
                 moved on                                        estimate (Estimate, Trajectory)

Offline forms of the same: ``pipeline`` (a recording read ahead on a worker thread while the graph
runs) and ``batch`` (many consecutive pairs per call of a sequence-form graph).
"""
