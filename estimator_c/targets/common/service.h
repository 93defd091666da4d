/* The board service shared by every target (firmware, native program): decodes the
 * host's messages, drives the estimator, measures its cost and answers. The target
 * supplies only byte output and a clock (board glue in targets/<name>/). */
#ifndef UWB_RIG_SERVICE_H
#define UWB_RIG_SERVICE_H

#include <stddef.h>
#include <stdint.h>

#include "estimator.h"
#include "protocol.h"

typedef struct {
    void (*write)(const uint8_t *data, size_t n);   /* blocking write of a whole frame */
    est_clock_t clock;                              /* timer ticks for the cost figures */
    uint8_t timer_unit;                             /* proto_timer_unit_t */
    uint32_t timer_hz;                              /* ticks per second (0: not a time base) */
} service_io_t;

typedef struct {
    estimator_t est;
    bias_net_t net;                 /* image received in chunks, installed on commit */
    proto_parser_t parser;
    service_io_t io;
    uint32_t window_cost;           /* ticks spent in the estimator since the last STEP */
    uint32_t frames_bad_reported;
} service_t;

void service_init(service_t *s, const service_io_t *io);
/* Announce a (re)start to the host (STATUS BOOT). */
void service_boot(service_t *s);
/* Feed received bytes; answers are written through io.write. */
void service_feed(service_t *s, const uint8_t *data, size_t n);

#endif
