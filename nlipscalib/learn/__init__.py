"""NLiPsNet: from a few dozen NLiPs-solved presses to real-time normals, depth and points from one tri-colour frame.

One module per job: ``dataset`` (calibration samples from solved presses), ``change`` (which pixels differ
from the reference frame), ``coverage`` (which regions / normal directions are covered, where to press
next), ``model`` / ``train`` (the paper's MLP, its model file, training split by press), ``onnx_export``,
``infer`` (one frame -> normals, depth, points), ``integrate`` (depth from normals on the dome along the
camera's rays), ``lut`` (GelSight-style lookup-table baseline), ``evaluate``, ``ply``, ``sensor``.
Reads captures through ``nlipscalib.core``; never imports ``solver`` or ``sim``.
"""
