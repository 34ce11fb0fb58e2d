// Bit timing at 16 MHz (62.5 ns per cycle), one bit every 20 cycles (800 kHz):
//   0 bit: high  5 cycles (312 ns), low 15 cycles (938 ns)
//   1 bit: high 12 cycles (750 ns), low  8 cycles (500 ns)
// The last bit of each byte stays low 3 cycles longer (loading the next byte); WS2812 tolerates low
// times up to several microseconds. Datasheets: WS2812B T0H 220-380 ns (V5) / 400+-150 ns, T1H 580-1000 ns.
// The simavr harness (firmware/simavr/harness.c) measures these edges on the emulated pin.
#include "ws2812.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/delay.h>

void ws2812_init() {
    WS2812_PORT &= ~_BV(WS2812_BIT);
    WS2812_DDR |= _BV(WS2812_BIT);
}

void ws2812_show(const uint8_t *grb, uint16_t count) {
    if (count == 0) return;
    const uint8_t sreg = SREG;
    cli();
    const uint8_t hi = WS2812_PORT | _BV(WS2812_BIT);
    const uint8_t lo = WS2812_PORT & ~_BV(WS2812_BIT);
    uint8_t byte, bits;
    asm volatile(
        "    ld   %[byte], %a[ptr]+ \n\t"
        "    ldi  %[bits], 8        \n\t"
        "1:  out  %[port], %[hi]    \n\t"  // c0: rising edge
        "    nop                    \n\t"  // c1
        "    nop                    \n\t"  // c2
        "    nop                    \n\t"  // c3
        "    sbrs %[byte], 7        \n\t"  // c4 (skips the next out when the bit is 1)
        "    out  %[port], %[lo]    \n\t"  // c5: falling edge of a 0 bit
        "    nop                    \n\t"  // c6
        "    nop                    \n\t"  // c7
        "    nop                    \n\t"  // c8
        "    nop                    \n\t"  // c9
        "    nop                    \n\t"  // c10
        "    nop                    \n\t"  // c11
        "    out  %[port], %[lo]    \n\t"  // c12: falling edge of a 1 bit
        "    lsl  %[byte]           \n\t"  // c13
        "    dec  %[bits]           \n\t"  // c14
        "    brne 2f                \n\t"  // c15 (2 cycles when taken)
        "    ld   %[byte], %a[ptr]+ \n\t"  // c16-17: next byte (reads one past the end after the last)
        "    ldi  %[bits], 8        \n\t"  // c18
        "    sbiw %[count], 1       \n\t"  // c19-20
        "    brne 1b                \n\t"  // c21-22: next rising edge at c23
        "    rjmp 3f                \n\t"
        "2:  nop                    \n\t"  // c17
        "    rjmp 1b                \n\t"  // c18-19: next rising edge at c20
        "3:                         \n\t"
        : [byte] "=&d"(byte), [bits] "=&d"(bits), [ptr] "+e"(grb), [count] "+w"(count)
        : [port] "I"(_SFR_IO_ADDR(WS2812_PORT)), [hi] "r"(hi), [lo] "r"(lo));
    SREG = sreg;
    _delay_us(300);  // latch: the line stays low >= 280 us, the LEDs now show the new colours
}
