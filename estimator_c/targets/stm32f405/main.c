/* STM32F405 firmware: the board service on USART1, or on the bulk link where an emulator
 * selected it (board.h). Runs unmodified on hardware and in qemu-system-arm -M
 * netduinoplus2. */
#include "board.h"
#include "service.h"

static service_t service;

int main(void)
{
    board_init();
    const int bulk = board_bulk_selected() && board_bulk_open() == 0;
    const service_io_t io = {.write = bulk ? board_bulk_write : board_write, .clock = board_clock,
                             .timer_unit = board_clock_unit(), .timer_hz = BOARD_CPU_HZ};
    service_init(&service, &io);
    service_boot(&service);
    if (bulk) board_bulk_flush();
    uint8_t buf[256];
    /* Poll rather than sleep (wfi): under QEMU a sleeping core delays the next received
     * byte by a host round trip, which halves the replay speed; a bench board has power.
     * The bulk link's read blocks in the emulator until the host sends. */
    for (;;) {
        const size_t n = bulk ? board_bulk_read(buf, sizeof buf) : board_read(buf, sizeof buf);
        if (n) {
            board_defer_tick(1);
            if (!bulk) service_note_lost(&service, board_rx_lost());
            service_feed(&service, buf, n);
            if (bulk) board_bulk_flush();
            board_defer_tick(0);
        }
    }
}
