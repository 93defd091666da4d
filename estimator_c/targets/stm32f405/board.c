/* STM32F405 board glue: 168 MHz clock from an 8 MHz crystal, USART1 (PA9/PA10) with
 * interrupt-driven receive and transmit ring buffers, and the cost clock (DWT cycle
 * counter, or TIM2 where the DWT does not count, as in QEMU).
 *
 * SysTick keeps a 1 ms uptime. The host paces the estimator with STEP messages, so the
 * tick drives nothing; its interrupt time, like the USART's, is taken out of the cost
 * clock so that counts measured around estimator calls do not depend on the host's timing. */
#include "board.h"

#include "protocol.h"

#include <string.h>

#define REG(addr) (*(volatile uint32_t *)(addr))

#define RCC_BASE 0x40023800u
#define RCC_CR REG(RCC_BASE + 0x00)
#define RCC_PLLCFGR REG(RCC_BASE + 0x04)
#define RCC_CFGR REG(RCC_BASE + 0x08)
#define RCC_AHB1ENR REG(RCC_BASE + 0x30)
#define RCC_APB1ENR REG(RCC_BASE + 0x40)
#define RCC_APB2ENR REG(RCC_BASE + 0x44)
#define FLASH_ACR REG(0x40023C00u)
#define GPIOA_MODER REG(0x40020000u)
#define GPIOA_AFRH REG(0x40020024u)
#define USART1_SR REG(0x40011000u)
#define USART1_DR REG(0x40011004u)
#define USART1_BRR REG(0x40011008u)
#define USART1_CR1 REG(0x4001100Cu)
#define TIM2_CR1 REG(0x40000000u)
#define TIM2_EGR REG(0x40000014u)
#define TIM2_CNT REG(0x40000024u)
#define TIM2_PSC REG(0x40000028u)
#define TIM2_ARR REG(0x4000002Cu)
#define NVIC_ISER1 REG(0xE000E104u)
#define SYST_CSR REG(0xE000E010u)
#define SYST_RVR REG(0xE000E014u)
#define SYST_CVR REG(0xE000E018u)
#define SHPR3 REG(0xE000ED20u)
#define TICK_PRIORITY 0xF0u
#define DEMCR REG(0xE000EDFCu)
#define DWT_CTRL REG(0xE0001000u)
#define DWT_CYCCNT REG(0xE0001004u)

#define SR_RXNE (1u << 5)
#define SR_TXE (1u << 7)
#define SR_ORE (1u << 3)
#define CR1_UE (1u << 13)
#define CR1_TXEIE (1u << 7)
#define CR1_RXNEIE (1u << 5)
#define CR1_TE (1u << 3)
#define CR1_RE (1u << 2)
#define USART1_IRQ 37u
#define READY_TIMEOUT 100000u   /* polls; emulators without a clock model never set ready bits */

/* State shared between the interrupt handlers and the main loop. */
static struct {
    volatile uint8_t rx[BOARD_RX_RING];
    volatile uint32_t rx_head, rx_tail;   /* head: written by the IRQ; tail: by the main loop */
    volatile uint32_t rx_lost;            /* bytes received into a full ring (IRQ) */
    volatile uint8_t tx[BOARD_TX_RING];
    volatile uint32_t tx_head, tx_tail;   /* head: main loop; tail: IRQ and kick */
    volatile uint32_t isr_ticks;          /* time spent in interrupts, not the estimator's */
    volatile uint32_t uptime_ms;          /* SysTick */
    uint8_t use_dwt;
} board;

static int wait_set(volatile uint32_t *reg, uint32_t mask, uint32_t value)
{
    for (uint32_t i = 0; i < READY_TIMEOUT; i++)
        if ((*reg & mask) == value) return 1;
    return 0;
}

/* HSE 8 MHz -> PLL (M 8, N 336, P 2, Q 7) -> 168 MHz SYSCLK, APB1 42 MHz, APB2 84 MHz.
 * If the crystal or PLL does not come up, the board stays on the 16 MHz HSI. */
static void clock_init(void)
{
    FLASH_ACR = (1u << 8) | (1u << 9) | (1u << 10) | 5u; /* prefetch, I/D caches, 5 wait states */
    RCC_CR |= 1u << 16;                                  /* HSEON */
    if (!wait_set(&RCC_CR, 1u << 17, 1u << 17)) return;  /* HSERDY */
    RCC_PLLCFGR = 8u | (336u << 6) | (0u << 16) | (1u << 22) | (7u << 24);
    RCC_CR |= 1u << 24;                                  /* PLLON */
    if (!wait_set(&RCC_CR, 1u << 25, 1u << 25)) return;  /* PLLRDY */
    RCC_CFGR = (RCC_CFGR & ~0xFCF3u) | (5u << 10) | (4u << 13) | 2u; /* APB1 /4, APB2 /2, SW = PLL */
    wait_set(&RCC_CFGR, 0xCu, 0x8u);                     /* SWS = PLL */
}

static void usart_init(void)
{
    RCC_AHB1ENR |= 1u << 0;    /* GPIOA */
    RCC_APB2ENR |= 1u << 4;    /* USART1 */
    GPIOA_MODER = (GPIOA_MODER & ~(0xFu << 18)) | (0xAu << 18);    /* PA9, PA10: alternate function */
    GPIOA_AFRH = (GPIOA_AFRH & ~(0xFFu << 4)) | (0x77u << 4);      /* AF7 = USART1 */
    USART1_BRR = (84000000u + BOARD_BAUD / 2) / BOARD_BAUD;        /* APB2 84 MHz, oversampling 16 */
    USART1_CR1 = CR1_UE | CR1_TE | CR1_RE | CR1_RXNEIE;
    NVIC_ISER1 = 1u << (USART1_IRQ - 32);
}

static void timers_init(void)
{
    DEMCR |= 1u << 24;         /* TRCENA */
    DWT_CYCCNT = 0;
    DWT_CTRL |= 1u;
    const uint32_t before = DWT_CYCCNT;
    for (volatile int i = 0; i < 100; i++) {
    }
    board.use_dwt = DWT_CYCCNT != before;
    RCC_APB1ENR |= 1u << 0;    /* TIM2: free-running 32-bit counter */
    TIM2_PSC = 0;
    TIM2_ARR = 0xFFFFFFFFu;
    TIM2_EGR = 1u;
    TIM2_CR1 = 1u;
}

static uint32_t raw_clock(void)
{
    return board.use_dwt ? DWT_CYCCNT : TIM2_CNT;
}

/* 1 kHz tick from the core clock (CLKSOURCE = processor, TICKINT, ENABLE), at the lowest
 * priority so that board_defer_tick can hold it off without holding off the USART. */
static void systick_init(void)
{
    SHPR3 = (SHPR3 & 0x00FFFFFFu) | (TICK_PRIORITY << 24);
    SYST_RVR = BOARD_CPU_HZ / 1000u - 1u;
    SYST_CVR = 0;
    SYST_CSR = 7u;
}

void systick_irq(void)
{
    const uint32_t start = raw_clock();
    board.uptime_ms++;
    board.isr_ticks += raw_clock() - start;
}

uint32_t board_uptime_ms(void)
{
    return board.uptime_ms;
}

void board_defer_tick(int defer)
{
    const uint32_t basepri = defer ? TICK_PRIORITY : 0u;
    __asm volatile("msr basepri, %0" : : "r"(basepri) : "memory");
}

void board_init(void)
{
    clock_init();
    usart_init();
    timers_init();
    systick_init();
}


/* Thread time: the counter minus the receive interrupt's own time, so a cost measured
 * around an estimator call does not depend on when the host's bytes happen to arrive. */
uint32_t board_clock(void)
{
    return raw_clock() - board.isr_ticks;
}

uint8_t board_clock_unit(void)
{
    return board.use_dwt ? PROTO_UNIT_CYCLES : PROTO_UNIT_INSTRUCTIONS;
}

/* Move bytes from the ring into the data register while it is empty. Called from the
 * interrupt and after every write (an emulated USART may report TXE without ever
 * raising the TXE interrupt). */
static void tx_pump(void)
{
    while ((USART1_SR & SR_TXE) && board.tx_tail != board.tx_head) {
        USART1_DR = board.tx[board.tx_tail & (BOARD_TX_RING - 1)];
        board.tx_tail++;
    }
    if (board.tx_tail == board.tx_head) USART1_CR1 &= ~CR1_TXEIE;
}

void usart1_irq(void)
{
    const uint32_t start = raw_clock();
    uint32_t sr = USART1_SR;
    while (sr & (SR_RXNE | SR_ORE)) {
        const uint8_t byte = (uint8_t)USART1_DR;  /* reading DR also clears ORE */
        if (board.rx_head - board.rx_tail < BOARD_RX_RING) {
            board.rx[board.rx_head & (BOARD_RX_RING - 1)] = byte;
            board.rx_head++;
        } else {
            board.rx_lost++;
        }
        sr = USART1_SR;
    }
    if (USART1_CR1 & CR1_TXEIE) tx_pump();
    board.isr_ticks += raw_clock() - start;
}

uint32_t board_rx_lost(void)
{
    return board.rx_lost;
}

size_t board_read(uint8_t *dst, size_t max)
{
    size_t n = 0;
    while (n < max && board.rx_tail != board.rx_head) {
        dst[n++] = board.rx[board.rx_tail & (BOARD_RX_RING - 1)];
        board.rx_tail++;
    }
    return n;
}

void board_write(const uint8_t *data, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        while (board.tx_head - board.tx_tail >= BOARD_TX_RING) {
            __asm volatile("cpsid i");
            tx_pump();
            __asm volatile("cpsie i");
        }
        board.tx[board.tx_head & (BOARD_TX_RING - 1)] = data[i];
        board.tx_head++;
    }
    __asm volatile("cpsid i");
    USART1_CR1 |= CR1_TXEIE;
    tx_pump();
    __asm volatile("cpsie i");
}

/* Written by the emulator before reset, never by the firmware (linker.ld: NOLOAD, outside
 * .bss). A magic word and its complement: power-on RAM never matches both by chance. */
__attribute__((section(".link_select"), used)) static volatile uint32_t link_select[2];

int board_bulk_selected(void)
{
    return link_select[0] == BOARD_BULK_MAGIC && link_select[1] == ~BOARD_BULK_MAGIC;
}

#define SYS_OPEN 0x01u
#define SYS_WRITE 0x05u
#define SYS_READ 0x06u
#define OPEN_READ 0u   /* "r" */
#define OPEN_WRITE 4u  /* "w" */

/* One semihosting call (ARM DUI 0471): BKPT 0xAB, operation in r0, parameter block in r1,
 * result in r0. */
static uint32_t semihost(uint32_t op, const uint32_t *block)
{
    register uint32_t r0 __asm("r0") = op;
    register const uint32_t *r1 __asm("r1") = block;
    __asm volatile("bkpt 0xab" : "+r"(r0) : "r"(r1) : "memory");
    return r0;
}

/* What the service says while it handles one read's worth of input goes out in one
 * SYS_WRITE after it (board_bulk_flush): every semihosting call stops the emulated core
 * and wakes the host once, and a window's answer is four frames. */
#define BULK_OUT_BYTES 256u

static struct {
    uint32_t in, out;   /* semihosting handles of the console (":tt") */
    uint8_t pending[BULK_OUT_BYTES];
    size_t n_pending;
} bulk;

static uint32_t console(uint32_t mode)
{
    static const char name[] = ":tt";
    const uint32_t block[3] = {(uint32_t)name, mode, sizeof name - 1};
    return semihost(SYS_OPEN, block);
}

int board_bulk_open(void)
{
    bulk.in = console(OPEN_READ);
    bulk.out = console(OPEN_WRITE);
    return bulk.in == 0xFFFFFFFFu || bulk.out == 0xFFFFFFFFu ? -1 : 0;
}

size_t board_bulk_read(uint8_t *dst, size_t max)
{
    const uint32_t block[3] = {bulk.in, (uint32_t)dst, max};
    const uint32_t missing = semihost(SYS_READ, block);   /* bytes not read */
    return missing <= max ? max - missing : 0;
}

static void bulk_write_now(const uint8_t *data, size_t n)
{
    const uint32_t block[3] = {bulk.out, (uint32_t)data, n};
    semihost(SYS_WRITE, block);
}

void board_bulk_flush(void)
{
    if (bulk.n_pending) bulk_write_now(bulk.pending, bulk.n_pending);
    bulk.n_pending = 0;
}

void board_bulk_write(const uint8_t *data, size_t n)
{
    if (bulk.n_pending + n > BULK_OUT_BYTES) board_bulk_flush();
    if (n > BULK_OUT_BYTES) {
        bulk_write_now(data, n);
        return;
    }
    memcpy(&bulk.pending[bulk.n_pending], data, n);
    bulk.n_pending += n;
}
