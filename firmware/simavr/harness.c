// Run the compiled LED firmware on an emulated ATmega328P (simavr) with its UART on a pseudo-terminal,
// so the host driver talks to it through pyserial exactly as to a USB board, and decode the WS2812 pin.
//
//   simavr-harness FIRMWARE.elf LINK     -> prints "READY <pty>" once LINK (a symlink to the pty) exists
//
// Control commands on stdin (one per line, each answered on stdout):
//   latched        "LATCHED <rgb hex> frames=N t0h=MIN-MAX t1h=MIN-MAX tlow=MIN-MAX early_acks=N ack_gap_us=MIN"
//                  (times in ns over every bit sent so far; rgb = the last latched frame, decoded from the pin)
//   reset          reset the MCU (reset button / watchdog): "OK reset"
//   drop N         lose the next N lines the board sends: "OK drop"
//   noise HEX      put raw bytes on the line to the host: "OK noise"
//   unplug MS      remove the port for MS ms, then recreate it and power-cycle the MCU: "OK unplug"
//   pace BAUD      carry bytes both ways at the wall-clock pace of an 8N1 line at BAUD (10 bits a byte; 0: as fast
//                  as the pseudo-terminal moves them, the default): "OK pace"
//   quit           also Ctrl-C, SIGTERM or the end of stdin: the link is removed and the harness exits 0
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "avr_ioport.h"
#include "avr_uart.h"
#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_irq.h"

#define FREQ 16000000UL
#define NS_PER_CYCLE (1e9 / FREQ)
#define LATCH_CYCLES (50 * 16)  // a WS2812 latches after >= 50 us low (we wait 280 us in firmware)
#define MAX_FRAME 512
#define UCSR0B_ADDR 0xC1  // ATmega328P USART0 control register B (data space address)
#define RXEN0_BIT 4

static avr_t *avr;
static const char *link_path;
static int master = -1, slave = -1;
static int xoff;
static uint8_t rxq[4096];
static size_t rxq_len;
static int drop_lines;
static double unplugged_until;  // wall time in s, 0 when plugged

// Line-rate pacing (`pace BAUD`): a pseudo-terminal has no line rate, so a byte is handed over (to the host or to the
// MCU's UART) only once a real line would have carried it, one byte time after the previous one ended.
static double byte_s;  // wall seconds per byte on the line, 0 when unpaced
static uint8_t txq[8192];  // board -> host, waiting for the line
static size_t txq_len;
static double tx_line_free, rx_line_free;  // wall time at which each direction's line finished its last byte

// WS2812 decoding
static uint64_t last_rise, last_fall;
static int pin_high;
static uint8_t frame[MAX_FRAME], shown[MAX_FRAME];
static int frame_bits, shown_len, frames;
static uint64_t t0h_min = UINT64_MAX, t0h_max, t1h_min = UINT64_MAX, t1h_max, tl_min = UINT64_MAX, tl_max;
static int early_acks;
static uint64_t ack_gap_min = UINT64_MAX, last_latch_end;
static int reply_pending_gap;  // 1 when a frame latched and no reply byte was sent since

static double now_s(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static void latch_if_idle(uint64_t cycle) {
    if (frame_bits && cycle - last_fall >= LATCH_CYCLES) {
        shown_len = frame_bits / 8;
        memcpy(shown, frame, shown_len);
        frames++;
        frame_bits = 0;
        last_latch_end = last_fall + LATCH_CYCLES;
        reply_pending_gap = 1;
    }
}

static void pin_changed(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq, (void)param;
    uint64_t c = avr->cycle;
    if (value && !pin_high) {
        latch_if_idle(c);
        if (frame_bits) {
            uint64_t low = c - last_fall;
            if (low < tl_min) tl_min = low;
            if (low > tl_max) tl_max = low;
        }
        last_rise = c;
    } else if (!value && pin_high) {
        uint64_t high = c - last_rise;
        int bit = high * NS_PER_CYCLE > 500.0;
        if (bit) {
            if (high < t1h_min) t1h_min = high;
            if (high > t1h_max) t1h_max = high;
        } else {
            if (high < t0h_min) t0h_min = high;
            if (high > t0h_max) t0h_max = high;
        }
        if (frame_bits < MAX_FRAME * 8) {
            int byte = frame_bits / 8, shift = 7 - frame_bits % 8;
            if (shift == 7) frame[byte] = 0;
            frame[byte] |= bit << shift;
            frame_bits++;
        }
        last_fall = c;
    }
    pin_high = value != 0;
}

static int at_line_start = 1, dropping;

static void uart_out(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq, (void)param;
    uint8_t b = value;
    if (at_line_start) {  // first byte of a line from the board: was the light latched before it?
        latch_if_idle(avr->cycle);
        if (frame_bits) early_acks++;
        if (reply_pending_gap) {
            uint64_t gap = avr->cycle - last_fall;
            if (gap < ack_gap_min) ack_gap_min = gap;
            reply_pending_gap = 0;
        }
        dropping = drop_lines > 0;
        if (dropping) drop_lines--;
    }
    at_line_start = b == '\n';
    if (dropping || master < 0) return;
    if (byte_s > 0) {
        if (txq_len == 0 && tx_line_free < now_s()) tx_line_free = now_s();  // the line was idle: starts now
        if (txq_len < sizeof txq) txq[txq_len++] = b;
    } else if (write(master, &b, 1) < 0 && errno != EAGAIN) {
        perror("harness: write");
    }
}

// Hand the host the bytes a paced line has finished carrying.
static void send_due_bytes(void) {
    size_t n = 0;
    for (double now = now_s(); n < txq_len && now >= tx_line_free + byte_s; n++) tx_line_free += byte_s;
    if (!n) return;
    if (master >= 0 && write(master, txq, n) < 0 && errno != EAGAIN) perror("harness: write");
    memmove(txq, txq + n, txq_len - n);
    txq_len -= n;
}

static void uart_xon(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq, (void)param, (void)value;
    xoff = 0;
}

static void uart_xoff(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq, (void)param;
    xoff = value != 0;
}

// The harness waits in poll() while the MCU sleeps, so simavr must not sleep to keep wall-clock pace.
static void no_sleep(avr_t *a, avr_cycle_count_t how_long) { (void)a, (void)how_long; }

static void quiet_uart(void) {
    uint32_t flags = 0;  // no console echo of UART output, no usleep on status polling
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
}

static void open_port(void) {
    struct termios tio;
    if (openpty(&master, &slave, NULL, NULL, NULL) < 0) {
        perror("harness: openpty");
        exit(1);
    }
    tcgetattr(slave, &tio);
    cfmakeraw(&tio);
    tcsetattr(slave, TCSANOW, &tio);
    fcntl(master, F_SETFL, fcntl(master, F_GETFL) | O_NONBLOCK);
    unlink(link_path);
    if (symlink(ptsname(master), link_path) < 0) {
        perror("harness: symlink");
        exit(1);
    }
}

static void close_port(void) {
    unlink(link_path);
    close(master);
    close(slave);
    master = slave = -1;
    rxq_len = txq_len = 0;
}

static void handle_command(char *cmd) {
    cmd[strcspn(cmd, "\r\n")] = 0;
    if (!strcmp(cmd, "latched")) {
        latch_if_idle(avr->cycle);
        printf("LATCHED ");
        for (int i = 0; i + 2 < shown_len; i += 3) printf("%02x%02x%02x", shown[i + 1], shown[i], shown[i + 2]);
        printf(" frames=%d t0h=%.0f-%.0f t1h=%.0f-%.0f tlow=%.0f-%.0f early_acks=%d ack_gap_us=%.1f\n", frames,
               t0h_min * NS_PER_CYCLE, t0h_max * NS_PER_CYCLE, t1h_min * NS_PER_CYCLE, t1h_max * NS_PER_CYCLE,
               tl_min * NS_PER_CYCLE, tl_max * NS_PER_CYCLE, early_acks,
               ack_gap_min == UINT64_MAX ? -1.0 : ack_gap_min * NS_PER_CYCLE / 1000.0);
    } else if (!strcmp(cmd, "reset")) {
        avr_reset(avr);
        quiet_uart();
        printf("OK reset\n");
    } else if (!strncmp(cmd, "drop ", 5)) {
        drop_lines += atoi(cmd + 5);
        printf("OK drop\n");
    } else if (!strncmp(cmd, "noise ", 6)) {
        for (char *h = cmd + 6; h[0] && h[1]; h += 2) {
            unsigned v;
            sscanf(h, "%2x", &v);
            uint8_t b = v;
            if (master >= 0 && write(master, &b, 1) < 0) perror("harness: noise");
        }
        printf("OK noise\n");
    } else if (!strncmp(cmd, "unplug ", 7)) {
        close_port();
        unplugged_until = now_s() + atoi(cmd + 7) / 1000.0;
        printf("OK unplug\n");
    } else if (!strncmp(cmd, "pace ", 5)) {
        int baud = atoi(cmd + 5);
        byte_s = baud > 0 ? 10.0 / baud : 0;
        tx_line_free = rx_line_free = now_s();
        printf("OK pace\n");
    } else if (!strcmp(cmd, "quit")) {
        unlink(link_path);
        exit(0);
    } else {
        printf("ERR unknown command %s\n", cmd);
    }
    fflush(stdout);
}

// Ctrl-C or SIGTERM of the harness: leave the loop and remove the link, as `quit` does. Killed by the default
// action instead, it left LINK pointing at a pseudo-terminal number the system gives to the next terminal opened.
static volatile sig_atomic_t stop_requested;
static void request_stop(int signum) {
    (void)signum;
    stop_requested = 1;
}

int main(int argc, char **argv) {
    if (argc != 3) {
        fprintf(stderr, "usage: %s FIRMWARE.elf LINK\n", argv[0]);
        return 2;
    }
    link_path = argv[2];
    elf_firmware_t fw;
    memset(&fw, 0, sizeof fw);
    if (elf_read_firmware(argv[1], &fw) != 0) {
        fprintf(stderr, "harness: cannot read %s\n", argv[1]);
        return 1;
    }
    avr = avr_make_mcu_by_name("atmega328p");
    avr_init(avr);
    fw.frequency = FREQ;
    avr_load_firmware(avr, &fw);
    avr->frequency = FREQ;
    avr->log = LOG_ERROR;
    avr->sleep = no_sleep;
    quiet_uart();
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), uart_out, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON), uart_xon, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), uart_xoff, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 6), pin_changed, NULL);
    avr_irq_t *uart_in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);

    // Boot until the firmware listens (USART0 receiver enabled), as a host opening a board that has been
    // powered for a while would find it; bytes sent before that would be lost, as on real hardware.
    for (long i = 0; i < 20000000L && !(avr->data[UCSR0B_ADDR] & (1 << RXEN0_BIT)); i++) avr_run(avr);
    open_port();
    struct sigaction on_stop;
    memset(&on_stop, 0, sizeof on_stop);
    on_stop.sa_handler = request_stop;  // no SA_RESTART: poll() returns at once with EINTR
    sigaction(SIGINT, &on_stop, NULL);
    sigaction(SIGTERM, &on_stop, NULL);
    printf("READY %s\n", ptsname(master));
    fflush(stdout);

    char cmd[1024];
    size_t cmd_len = 0;
    int sleeping_runs = 0;
    while (!stop_requested) {
        if (unplugged_until) {  // no power: the MCU does not run
            if (now_s() < unplugged_until) {
                usleep(2000);
            } else {
                unplugged_until = 0;
                open_port();
                avr_reset(avr);
                quiet_uart();
            }
        } else {
            for (int i = 0; i < 4000; i++) {
                int state = avr_run(avr);
                if (state == cpu_Done || state == cpu_Crashed) {
                    fprintf(stderr, "harness: the MCU stopped (state %d)\n", state);
                    return 1;
                }
                sleeping_runs = state == cpu_Sleeping ? sleeping_runs + 1 : 0;
                if (sleeping_runs > 8) break;
            }
        }
        // Feed the UART from the host side while its FIFO has room (paced: each byte once the line carried it).
        double now = byte_s > 0 ? now_s() : 0;
        while (rxq_len && !xoff && (byte_s <= 0 || now >= rx_line_free + byte_s)) {
            avr_raise_irq(uart_in, rxq[0]);
            memmove(rxq, rxq + 1, --rxq_len);
            rx_line_free += byte_s;
        }
        if (txq_len) send_due_bytes();
        // Idle (asleep, nothing queued): block in poll instead of spinning the emulator.
        int asleep = sleeping_runs > 8, idle = asleep && rxq_len == 0 && txq_len == 0;
        // Asleep with paced bytes on the line: wait for the next one's end in ppoll, not by spinning the emulator
        double wait_s = idle ? 0.002 : 0;
        if (asleep && !idle && byte_s > 0) {
            double due = 1e30;
            if (txq_len) due = tx_line_free + byte_s;
            if (rxq_len && !xoff && rx_line_free + byte_s < due) due = rx_line_free + byte_s;
            wait_s = due - now_s();
            if (wait_s < 0) wait_s = 0;
            if (wait_s > 0.002) wait_s = 0.002;
        }
        struct timespec wait = {0, (long)(wait_s * 1e9)};
        struct pollfd fds[2] = {{0, POLLIN, 0}, {master, POLLIN, 0}};
        int n = ppoll(fds, master >= 0 ? 2 : 1, &wait, NULL);
        if (n > 0 && (fds[0].revents & (POLLIN | POLLHUP))) {
            ssize_t got = read(0, cmd + cmd_len, sizeof cmd - 1 - cmd_len);
            if (got <= 0) break;  // the test process went away
            cmd_len += got;
            char *nl;
            while ((nl = memchr(cmd, '\n', cmd_len))) {
                *nl = 0;
                handle_command(cmd);
                size_t used = nl + 1 - cmd;
                memmove(cmd, nl + 1, cmd_len - used);
                cmd_len -= used;
            }
        }
        if (n > 0 && master >= 0 && (fds[1].revents & POLLIN) && rxq_len < sizeof rxq) {
            if (rxq_len == 0 && rx_line_free < now_s()) rx_line_free = now_s();  // the line was idle: starts now
            ssize_t got = read(master, rxq + rxq_len, sizeof rxq - rxq_len);
            if (got > 0) rxq_len += got;
        }
        if (idle) latch_if_idle(avr->cycle);
    }
    unlink(link_path);
    return 0;
}
