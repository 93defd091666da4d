/* libFuzzer target: arbitrary bytes into the board service, as a host (or line noise)
 * could send them: the frame parser, every message handler (delta-coded IMU, packed
 * TDOA, network chunks, parameters) and the estimator behind them. Built with ASan and
 * UBSan (make fuzz); a crash, an overflow or undefined behaviour is a finding.
 * Each input is one session: the service starts fresh, as after a board reset. */
#include <stddef.h>
#include <stdint.h>

#include "service.h"

static void discard(const uint8_t *data, size_t n)
{
    (void)data;
    (void)n;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static service_t service;   /* 10 kB: kept off the fuzzer's stack */
    const service_io_t io = {.write = discard};
    service_init(&service, &io);
    service_boot(&service);
    service_feed(&service, data, size);
    return 0;
}
