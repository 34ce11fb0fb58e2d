"""Types shared by every part of the workbench: camera, LEDs, the capture format.

sim/ and device/ write captures with these; solver/ and learn/ read them. Nothing here imports any
heavy optional dependency at import time.
"""

from .camera import Camera
from .capture import Press, load_press, write_press
from .leds import Led, disk_shading, led_arrays, led_shading, tricolor_colors, tricolor_groups
from .press_folders import find_presses, is_press_folder
from .reconstruction import Reconstruction, load_reconstruction, save_reconstruction
from .sensor import CameraConfig, DomeConfig, LedConfig, SensorDesign
from .sensor_response import SensorResponse
from .surface_files import GroundTruth, Reference

__all__ = [
    "Camera",
    "CameraConfig",
    "DomeConfig",
    "GroundTruth",
    "Led",
    "LedConfig",
    "Press",
    "Reconstruction",
    "Reference",
    "SensorDesign",
    "SensorResponse",
    "find_presses",
    "is_press_folder",
    "led_arrays",
    "led_shading",
    "disk_shading",
    "load_press",
    "load_reconstruction",
    "save_reconstruction",
    "tricolor_colors",
    "tricolor_groups",
    "write_press",
]
