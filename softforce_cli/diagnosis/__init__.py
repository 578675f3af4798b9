"""Model-discrepancy diagnosis (`softforce diagnose`): where the FE model and the observed robot
disagree, which missing physics explains it, its fitted parameters, and the fit's improvement.

Stages, one module each: observations (frames -> robot points), states (frames -> distinct
actuation states, one FE solve each), prediction (the FE surface per state, with effects and
the mesh correction), residuals (normal distances to the predicted surface), hypotheses (the
candidate effects and their sensitivities), fitting (least squares over an effect's
parameters), selection (held-out error by leaving trajectory segments out), report (the
diagnosis.json document and robot.fitted.toml), figures, and pipeline (the whole run).
"""
