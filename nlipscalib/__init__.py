"""NLiPsCalib: calibrate curved visuotactile sensors with near-light photometric stereo."""

__version__ = "0.1.0"
