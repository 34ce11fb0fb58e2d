"""Exceptions shared by every part of the workbench.

All are ``ValueError`` subclasses so that callers who only know numpy-style errors still catch them;
the CLI turns them into one readable line instead of a traceback.
"""

from __future__ import annotations

from types import ModuleType


class NlipsError(ValueError):
    """Base class of every error the workbench raises on purpose."""


class ConfigError(NlipsError):
    """A scene, press or dataset spec is wrong (the message names the file and the key)."""


class CaptureError(NlipsError):
    """A press folder is missing something or holds inconsistent data (the message names the file)."""


class NoContactError(CaptureError):
    """``--roi auto`` found no contact: the press's images match the undeformed dome within noise. A folder solve
    notes the press and goes on (not a failure); ``nlips solve PRESS`` refuses it in one line."""


class DeviceError(NlipsError):
    """The LED controller or camera failed: port missing, no permission, no answer, wrong firmware, reset."""


class ShapeError(NlipsError):
    """An array given to a public function has the wrong shape or dtype."""


class MissingDependencyError(ImportError):
    """An optional heavy dependency (mitsuba, OpenCV, onnxruntime, pyserial, torch) is not installed."""


def require(module: str, extra: str, purpose: str) -> ModuleType:
    """Import an optional module or fail with a message saying how to install it.

    Parameters
    ----------
    module : str
        Importable module name, e.g. ``"cv2"``.
    extra : str
        pip requirement that provides it, e.g. ``"opencv-python-headless"``.
    purpose : str
        What needs it, shown to the user.
    """
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise MissingDependencyError(
            f"{purpose} needs the optional package '{module}'. Install it with: pip install {extra}"
        ) from exc
