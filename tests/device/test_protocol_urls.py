"""The controller opens any pyserial URL: socket:// (a board behind ser2net) and the project's nlipsemu://."""

import socket
import threading

import numpy as np
import serial

from nlipscalib.device.controller import LedController
from nlipscalib.device.virtual_board import VirtualBoard


class Ser2Net:
    """A TCP server relaying one connection to a serial URL, as ser2net does for a board on another machine."""

    def __init__(self, url: str):
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.url = url
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self):
        conn, _ = self.server.accept()
        conn.settimeout(0.01)
        with conn, serial.serial_for_url(self.url, timeout=0.01) as port:
            while not self.stop.is_set():
                try:
                    data = conn.recv(4096)
                    if not data:
                        return
                    port.write(data)
                except TimeoutError:
                    pass
                if waiting := port.in_waiting:
                    conn.sendall(port.read(waiting))

    def close(self):
        self.stop.set()
        self.thread.join(5)
        self.server.close()


def test_socket_url_reaches_a_board_behind_a_relay():
    board = VirtualBoard(6)
    relay = Ser2Net(board.url)
    try:
        with LedController.open(f"socket://127.0.0.1:{relay.port}", timeout=1.0) as leds:
            assert leds.n_leds == 6
            frame = np.arange(18, dtype=np.uint8).reshape(6, 3)
            leds.set_all(frame)
            np.testing.assert_array_equal(board.latched, frame)
            np.testing.assert_array_equal(leds.state(), frame)
    finally:
        relay.close()


def test_nlipsemu_url_through_plain_pyserial():
    board = VirtualBoard(2, reset_on_open=False)
    with serial.serial_for_url(board.url, timeout=1.0) as port:
        port.write(b">01 HELLO*cae2\n")
        assert port.readline().startswith(b"<01 OK fw=")
