/* Cortex-M4F start-up for the STM32F405: vector table, .data/.bss initialisation,
 * FPU enable, then main(). Written for this project; no vendor code. */
#include <stdint.h>

extern uint32_t _stack_top, _data_load, _data_start, _data_end, _bss_start, _bss_end;
int main(void);
void usart1_irq(void);
void systick_irq(void);

#define SCB_CPACR (*(volatile uint32_t *)0xE000ED88u)

void reset_handler(void)
{
    uint32_t *src = &_data_load;
    for (uint32_t *dst = &_data_start; dst < &_data_end;) *dst++ = *src++;
    for (uint32_t *dst = &_bss_start; dst < &_bss_end;) *dst++ = 0;
    SCB_CPACR |= 0xFu << 20; /* CP10 and CP11 full access: the FPU */
    __asm volatile("dsb\n isb");
    main();
    for (;;) {
    }
}

static void default_handler(void)
{
    for (;;) {
    }
}

#define N_IRQ 82
typedef void (*vector_t)(void);

/* 16 system exceptions, then the STM32F405's interrupts; USART1 is IRQ 37. */
__attribute__((section(".isr_vector"), used)) const vector_t vector_table[16 + N_IRQ] = {
    [0] = (vector_t)&_stack_top,
    [1] = reset_handler,
    [2] = default_handler,  /* NMI */
    [3] = default_handler,  /* HardFault */
    [4] = default_handler,  /* MemManage */
    [5] = default_handler,  /* BusFault */
    [6] = default_handler,  /* UsageFault */
    [11] = default_handler, /* SVCall */
    [14] = default_handler, /* PendSV */
    [15] = systick_irq,     /* 1 ms uptime (board.c) */
    [16 + 37] = usart1_irq,
};
