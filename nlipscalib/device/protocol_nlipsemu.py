"""pyserial URL handler for ``nlipsemu://<id>`` (pyserial imports ``<package>.protocol_<scheme>``)."""

from .virtual_board import VirtualSerial as Serial

__all__ = ["Serial"]
