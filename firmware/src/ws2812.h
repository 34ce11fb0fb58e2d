// WS2812 ("NeoPixel") output by cycle-counted bit-banging, for a 16 MHz AVR (ATmega328P, Arduino Uno/Nano).
#pragma once
#include <stdint.h>

#if F_CPU != 16000000UL
#error "ws2812.cpp is cycle-counted for F_CPU = 16 MHz"
#endif

// Data pin: Arduino D6 = PD6 unless the build overrides these.
#ifndef WS2812_PORT
#define WS2812_PORT PORTD
#define WS2812_DDR DDRD
#define WS2812_BIT 6
#endif

void ws2812_init();

// Send `count` bytes (GRB order, 3 per LED) to the strip, then hold the line low for the latch (>= 280 us),
// so the LEDs show the new colours when this returns. Interrupts are off while the bits go out.
void ws2812_show(const uint8_t *grb, uint16_t count);
