// nlips LED controller firmware: the nlips LED line protocol v1 (docs/protocol.md) on USART0 at 115200 baud,
// WS2812 LEDs on D6. Every command is answered after the LEDs latched.
//
// Line from the host: ">SS CMD ARGS*CCCC\n"; reply: "<SS OK ...*CCCC\n" or "<SS E<n> NAME*CCCC\n";
// boot banner "!BOOT fw=.. proto=1 leds=N sid=XXXX*CCCC\n". CCCC = CRC-16/XMODEM of the text between the
// start marker and '*' (avr-libc's _crc_xmodem_update; Python's binascii.crc_hqx).
#include <avr/eeprom.h>
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <string.h>
#include <util/crc16.h>

#include "uart.h"
#include "ws2812.h"

#ifndef NLEDS
#define NLEDS 12
#endif
// RAM of the ATmega328P is 2048 bytes: 15 per LED in the buffers below (pending, latched, wire, line), about 330
// for the rest (UART ring buffer, strings) and the call stack with the receive interrupt on top. At 100 LEDs
// 218 bytes are left for the stack; past ~113 the buffers do not link, and past 255 the byte-wide LED loops
// would never end. Refused here, with the reason, instead of a board that crashes on its first ALL.
#define NLEDS_MAX 100
#if NLEDS < 1 || NLEDS > NLEDS_MAX
#error "NLEDS must be 1..100 on the ATmega328P (2 KB RAM, 15 bytes per LED plus the stack): firmware/README.md"
#endif
#define FW_VERSION "1.0.0"
#define PROTOCOL_VERSION "1"
#define MAX_LINE (6 * NLEDS + 32)

enum Error : uint8_t { E_CRC = 1, E_SYNTAX, E_UNKNOWN, E_RANGE, E_COUNT, E_LONG, E_NOSESSION };
static const char *const ERROR_NAMES[] = {"", "CRC", "SYNTAX", "UNKNOWN", "RANGE", "COUNT", "LONG", "NOSESSION"};

static uint8_t pending[NLEDS * 3];  // RGB, staged by SET/PUT/ALL/OFF
static uint8_t latched[NLEDS * 3];  // RGB, what the LEDs show
static uint8_t wire[NLEDS * 3];     // GRB, the order WS2812 expects; ALL parses into it (latch() rewrites it)
static char line[MAX_LINE + 1];
static uint16_t line_len;
static bool in_line, line_too_long, session_open;
static uint16_t session_id;
static uint16_t tx_crc;

// --- replies: streamed byte by byte, CRC computed on the way --------------------------------------------
static void put(char c) {
    uart_write(c);
    tx_crc = _crc_xmodem_update(tx_crc, c);
}
static void put_str(const char *s) {
    while (*s) put(*s++);
}
static void put_hex8(uint8_t v) {
    static const char digits[] = "0123456789abcdef";
    put(digits[v >> 4]);
    put(digits[v & 15]);
}
static void put_uint(uint16_t v) {
    char buf[6];
    uint8_t n = 0;
    do {
        buf[n++] = '0' + v % 10;
        v /= 10;
    } while (v);
    while (n) put(buf[--n]);
}
static void begin_line(char marker) {
    uart_write(marker);
    tx_crc = 0;
}
static void end_line() {
    const uint16_t crc = tx_crc;
    uart_write('*');
    put_hex8(crc >> 8);
    put_hex8(crc & 0xff);
    uart_write('\n');
}
static void begin_reply(const char *seq) {
    begin_line('<');
    put(seq[0]);
    put(seq[1]);
    put(' ');
}
static void reply_error(const char *seq, uint8_t code) {
    begin_reply(seq);
    put('E');
    put_uint(code);
    put(' ');
    put_str(ERROR_NAMES[code]);
    end_line();
}
static void reply_ok(const char *seq) {
    begin_reply(seq);
    put_str("OK");
    end_line();
}
static void put_info() {
    put_str("fw=" FW_VERSION " proto=" PROTOCOL_VERSION " leds=");
    put_uint(NLEDS);
    put_str(" sid=");
    put_hex8(session_id >> 8);
    put_hex8(session_id & 0xff);
}

// --- parsing ---------------------------------------------------------------------------------------------
static int8_t hex_digit(char c) {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}
// Parse `n` bytes of hex from `s` into `out`; false on a bad digit.
static bool parse_hex(const char *s, uint8_t *out, uint16_t n) {
    for (uint16_t i = 0; i < n; ++i) {
        const int8_t a = hex_digit(s[2 * i]), b = hex_digit(s[2 * i + 1]);
        if (a < 0 || b < 0) return false;
        out[i] = (a << 4) | b;
    }
    return true;
}
static bool parse_index(const char *s, uint16_t *out) {
    uint16_t v = 0;
    uint8_t n = 0;
    for (; *s; ++s, ++n) {
        if (*s < '0' || *s > '9' || n >= 3) return false;
        v = v * 10 + (*s - '0');
    }
    *out = v;
    return n > 0;
}

// --- LEDs ------------------------------------------------------------------------------------------------
static void latch() {
    memcpy(latched, pending, sizeof latched);
    for (uint8_t i = 0; i < NLEDS; ++i) {
        wire[3 * i] = latched[3 * i + 1];  // G
        wire[3 * i + 1] = latched[3 * i];  // R
        wire[3 * i + 2] = latched[3 * i + 2];
    }
    ws2812_show(wire, sizeof wire);
}

// --- commands --------------------------------------------------------------------------------------------
// Split `body` (NUL-terminated, without seq) at single spaces into at most 3 tokens; returns the count,
// or 0 for an empty token (leading, trailing or double space) or more than 3 tokens.
static uint8_t split(char *body, char **tok) {
    uint8_t n = 0;
    for (;;) {
        if (n == 3 || *body == ' ' || !*body) return 0;
        tok[n++] = body;
        while (*body && *body != ' ') ++body;
        if (!*body) return n;
        *body++ = '\0';
    }
}

static void execute(const char *seq, char *body) {
    char *tok[3];
    const uint8_t n = split(body, tok);
    if (n == 0) return reply_error(seq, E_SYNTAX);
    const char *cmd = tok[0];
    const bool hello = strcmp(cmd, "HELLO") == 0;
    if (!hello && strcmp(cmd, "SET") && strcmp(cmd, "PUT") && strcmp(cmd, "ALL") && strcmp(cmd, "OFF") &&
        strcmp(cmd, "SHOW") && strcmp(cmd, "STATE"))
        return reply_error(seq, E_UNKNOWN);
    if (!hello && !session_open) return reply_error(seq, E_NOSESSION);
    if (hello || !strcmp(cmd, "OFF") || !strcmp(cmd, "SHOW") || !strcmp(cmd, "STATE")) {
        if (n != 1) return reply_error(seq, E_SYNTAX);
        if (hello) {
            session_open = true;
            begin_reply(seq);
            put_str("OK ");
            put_info();
            return end_line();
        }
        if (!strcmp(cmd, "STATE")) {
            begin_reply(seq);
            put_str("OK ");
            for (uint16_t i = 0; i < sizeof latched; ++i) put_hex8(latched[i]);
            return end_line();
        }
        if (!strcmp(cmd, "OFF")) memset(pending, 0, sizeof pending);
        latch();
        return reply_ok(seq);
    }
    if (!strcmp(cmd, "ALL")) {
        if (n != 2) return reply_error(seq, E_SYNTAX);
        const uint16_t len = strlen(tok[1]);
        if (len != 6 * NLEDS) return reply_error(seq, len % 6 ? E_SYNTAX : E_COUNT);
        // parsed into `wire`, not a local array: 3 bytes per LED more on the stack crashed the board from 100
        // LEDs (simavr), and `pending` stays untouched when a digit is bad
        if (!parse_hex(tok[1], wire, sizeof wire)) return reply_error(seq, E_SYNTAX);
        memcpy(pending, wire, sizeof pending);
        latch();
        return reply_ok(seq);
    }
    // SET / PUT index rrggbb
    uint16_t index;
    uint8_t rgb[3];
    if (n != 3 || !parse_index(tok[1], &index) || strlen(tok[2]) != 6 || !parse_hex(tok[2], rgb, 3))
        return reply_error(seq, E_SYNTAX);
    if (index >= NLEDS) return reply_error(seq, E_RANGE);
    memcpy(pending + 3 * index, rgb, 3);
    if (cmd[0] == 'S') latch();
    reply_ok(seq);
}

static void handle_line() {
    line[line_len] = '\0';
    char seq[3] = {'-', '-', '\0'};
    if (line_len >= 2 && hex_digit(line[0]) >= 0 && hex_digit(line[1]) >= 0) {
        seq[0] = line[0];
        seq[1] = line[1];
    }
    if (line_too_long) return reply_error(seq, E_LONG);
    char *star = strrchr(line, '*');
    uint8_t crc_bytes[2];
    if (!star || strlen(star + 1) != 4 || !parse_hex(star + 1, crc_bytes, 2)) return reply_error(seq, E_CRC);
    uint16_t crc = 0;
    for (const char *c = line; c < star; ++c) crc = _crc_xmodem_update(crc, *c);
    if (crc != ((uint16_t)crc_bytes[0] << 8 | crc_bytes[1])) return reply_error(seq, E_CRC);
    *star = '\0';
    if (line_len < 3 || line[2] != ' ' || seq[0] == '-') return reply_error(seq, E_SYNTAX);
    execute(seq, line + 3);
}

// '>' starts a line (dropping any half line before it), '\n' ends it, bytes outside a line are ignored.
static void receive(uint8_t c) {
    if (c == '>') {
        in_line = true;
        line_too_long = false;
        line_len = 0;
    } else if (!in_line || c == '\r') {
        return;
    } else if (c == '\n') {
        in_line = false;
        handle_line();
    } else if (line_len < MAX_LINE) {
        line[line_len++] = c;
    } else {
        line_too_long = true;
    }
}

static void boot() {
    // Session id: a boot counter in EEPROM, so every boot (reset, power cycle) announces a new one.
    uint16_t *const counter = (uint16_t *)0;
    session_id = eeprom_read_word(counter) + 1;
    eeprom_update_word(counter, session_id);
    ws2812_init();
    latch();  // all off
    uart_init();
    sei();
    begin_line('!');
    put_str("BOOT ");
    put_info();
    end_line();
}

int main() {
    boot();
    set_sleep_mode(SLEEP_MODE_IDLE);
    for (;;) {
        int16_t c;
        while ((c = uart_read()) >= 0) receive(c);
        // Sleep until the next byte arrives (the UART interrupt wakes us); check again with interrupts off
        // so a byte that arrived in between is not slept over.
        cli();
        if ((c = uart_read()) >= 0) {
            sei();
            receive(c);
            continue;
        }
        sleep_enable();
        sei();
        sleep_cpu();
        sleep_disable();
    }
}
