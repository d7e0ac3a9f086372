"""Training of the bottom-up posture estimator (``harness.engine.bottom_up``): the data the harness simulates
(``data``), the fit and its scores (``train``), the command ``harness train-posture`` (``cli``). Outside the engine:
it simulates with ``harness.scene``."""
