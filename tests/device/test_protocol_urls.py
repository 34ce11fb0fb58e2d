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


def test_a_serial_device_keeps_dtr_up_when_closed_so_an_uno_is_not_reset_by_the_next_command():
    """A USB serial port drops DTR on close (HUPCL, the kernel's default), and an Uno resets when DTR rises on the
    next open: ``nlips leds PORT set ...`` then ``nlips leds PORT state`` found every LED dark. The driver clears
    HUPCL on the device it opens (a pseudo-terminal stands in for /dev/ttyACM0: it has the flag, not the DTR line)."""
    import os
    import pty
    import termios

    from nlipscalib.device.controller import open_port

    master, slave = pty.openpty()
    try:
        attrs = termios.tcgetattr(slave)
        attrs[2] |= termios.HUPCL  # as a freshly plugged-in ttyACM has it
        termios.tcsetattr(slave, termios.TCSANOW, attrs)
        port = open_port(os.ttyname(slave))
        port.close()
        assert not termios.tcgetattr(slave)[2] & termios.HUPCL
        open_port("loop://").close()  # a URL without a terminal device behind it opens as before
    finally:
        os.close(master)
        os.close(slave)


def test_a_socket_url_with_no_server_is_one_line_naming_the_server(capsys):
    """It said "socket://127.0.0.1:P: could not open the port: Could not open port socket://127.0.0.1:P: [Errno
    111] Connection refused": the URL twice, and nothing on what to check."""
    from nlipscalib.cli import main

    with socket.socket() as probe:  # a port nothing listens on: bound here, closed before the command connects
        probe.bind(("127.0.0.1", 0))
        url = f"socket://127.0.0.1:{probe.getsockname()[1]}"
    assert main(["leds", url, "info"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"nlips leds: error: {url}: could not connect (") and err.count(url) == 1, err
    assert err.endswith(
        "is the serial server (ser2net, an RFC 2217 server, esp-link) running at this host and port, "
        "and reachable from here?"
    ), err
