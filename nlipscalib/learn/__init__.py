"""NLiPsNet: from a few dozen NLiPs-solved presses to real-time normals, depth and points from one tri-colour frame.

One module per job: ``dataset`` (calibration samples from solved presses), ``change`` (which pixels differ
from the reference frame), ``coverage`` (which regions / normal directions are covered, where to press
next), ``prefilter`` (the low-pass filter of the frame before the network), ``model`` / ``train`` (the
paper's MLP, its model file, training split by press), ``onnx_export``, ``infer`` (one frame -> normals,
depth, points, on the CPU), ``fullframe`` (the same with every step on a GPU), ``cuda_graph`` (replaying a
frame's kernels as one CUDA graph), ``integrate`` / ``integrate_torch`` (depth from normals on the dome
along the camera's rays, in NumPy/SciPy and in PyTorch), ``lut`` (GelSight-style lookup-table baseline),
``evaluate`` (scoring predictors on held-out presses), ``seen`` (whether a model learnt from the capture it
reads), ``ply`` (point cloud export), ``watch`` (a stream's frames unlike the calibration's, warned about once).
Reads captures, and the sensor a model was calibrated for (``core.sensor_record``), through
``nlipscalib.core``; never imports ``solver`` or ``sim``.
"""
