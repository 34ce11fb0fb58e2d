#include "uart.h"

#include <avr/interrupt.h>
#include <avr/io.h>

// 128-byte ring buffer: at 115200 baud the host sends one command and waits for its reply, so this only
// has to absorb a burst of garbage while the main loop is busy.
static volatile uint8_t rx_buf[128];
static volatile uint8_t rx_head, rx_tail;

void uart_init() {
    UCSR0A = _BV(U2X0);  // double speed: UBRR 16 gives 117647 baud (+2.1 %), as the Arduino core does
    UBRR0 = (F_CPU / 8 / UART_BAUD) - 1;
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);  // 8N1
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
}

ISR(USART_RX_vect) {
    const uint8_t byte = UDR0;
    const uint8_t next = (rx_head + 1) & 127;
    if (next != rx_tail) {  // when full, drop: the line's CRC makes the host resend
        rx_buf[rx_head] = byte;
        rx_head = next;
    }
}

int16_t uart_read() {
    if (rx_tail == rx_head) return -1;
    const uint8_t byte = rx_buf[rx_tail];
    rx_tail = (rx_tail + 1) & 127;
    return byte;
}

void uart_write(uint8_t byte) {
    while (!(UCSR0A & _BV(UDRE0))) {
    }
    UDR0 = byte;
}
