"""The studies over trained runs and over the physics: evaluation against the expert and the
baselines, results across seeds, sweeps, the physics checks of a grip and the agreement of
the analytic verdict with MuJoCo's."""
