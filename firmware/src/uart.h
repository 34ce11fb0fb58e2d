// USART0 at 115200 baud: interrupt-driven receive into a ring buffer, polled transmit.
#pragma once
#include <stdint.h>

#define UART_BAUD 115200UL

void uart_init();
// Next received byte, or -1 when none is waiting.
int16_t uart_read();
void uart_write(uint8_t byte);
