/* Board glue for the STM32F405 (registers from the reference manual RM0090). */
#ifndef UWB_RIG_BOARD_H
#define UWB_RIG_BOARD_H

#include <stddef.h>
#include <stdint.h>

#define BOARD_CPU_HZ 168000000u
#define BOARD_BAUD 921600u
#ifndef BOARD_RX_RING
#define BOARD_RX_RING 1024u     /* power of two (a test build makes it small, to overflow it) */
#endif
#define BOARD_TX_RING 512u      /* power of two */

void board_init(void);
uint32_t board_uptime_ms(void);  /* SysTick */
/* Hold the tick interrupt off (1) while the service works, so that it never lands inside
 * a measured estimator call; a tick that falls due meanwhile runs on release (0). */
void board_defer_tick(int defer);
/* The cost clock: DWT cycles on hardware; TIM2 (one count per instruction under QEMU
 * -icount shift=0) where the DWT counter does not run. Time spent in the USART
 * interrupt is excluded (see board.c). */
uint32_t board_clock(void);
uint8_t board_clock_unit(void);       /* proto_timer_unit_t of board_clock */
size_t board_read(uint8_t *dst, size_t max);
void board_write(const uint8_t *data, size_t n);

/* The bulk link: the host's bytes through ARM semihosting (SYS_READ and SYS_WRITE on the
 * console, which QEMU connects to a chardev), a whole buffer per call instead of one
 * USART byte per emulated interrupt. Only where an emulator selected it, writing
 * BOARD_BULK_MAGIC and its complement into the last RAM words before reset
 * (`-device loader`): on a board without a debugger a semihosting call is a fault. */
#define BOARD_BULK_MAGIC 0x6B6C7562u   /* "bulk" */
/* Bytes the USART received while the receive ring was full, since boot: lost before
 * the service saw them. */
uint32_t board_rx_lost(void);
int board_bulk_selected(void);
int board_bulk_open(void);             /* 0 on success */
size_t board_bulk_read(uint8_t *dst, size_t max);  /* blocks until at least one byte */
void board_bulk_write(const uint8_t *data, size_t n);   /* held until board_bulk_flush */
void board_bulk_flush(void);

#endif
