/* STM32F405 firmware: the board service on USART1. Runs unmodified on hardware and in
 * qemu-system-arm -M netduinoplus2. */
#include "board.h"
#include "service.h"

static service_t service;

int main(void)
{
    board_init();
    const service_io_t io = {.write = board_write, .clock = board_clock, .timer_unit = board_clock_unit(),
                             .timer_hz = BOARD_CPU_HZ};
    service_init(&service, &io);
    service_boot(&service);
    uint8_t buf[64];
    /* Poll rather than sleep (wfi): under QEMU a sleeping core delays the next received
     * byte by a host round trip, which halves the replay speed; a bench board has power. */
    for (;;) {
        const size_t n = board_read(buf, sizeof buf);
        if (n) {
            board_defer_tick(1);
            service_feed(&service, buf, n);
            board_defer_tick(0);
        }
    }
}
