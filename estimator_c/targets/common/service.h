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
    /* Packet links (a CRTP app channel: one message per packet, the link frames and
     * checks it): when set, answers go out here as bare payloads instead of frames. */
    void (*packet)(const uint8_t *payload, size_t n);
    est_clock_t clock;                              /* timer ticks for the cost figures */
    uint8_t timer_unit;                             /* proto_timer_unit_t */
    uint32_t timer_hz;                              /* ticks per second (0: not a time base) */
} service_io_t;

/* Receiver side of the delta-coded IMU stream. */
typedef struct {
    int16_t last[PROTO_IMU_AXES];   /* the previous sample: reference of the next delta */
    uint8_t next_seq;               /* sequence number the next IMU message must carry */
    uint8_t valid;                  /* 0 until a key message arrives, and after a lost one */
    uint16_t lost;                  /* delta messages dropped for a missing reference */
} imu_stream_t;

/* The cost of one window as TIMING reports it, in the timer unit of the hello reply. */
typedef struct {
    uint32_t t_us, window, predict, tdoa_total, tdoa_max;
    uint8_t n_tdoa;
} window_timing_t;

typedef struct {
    estimator_t est;
    bias_net_t net;                 /* image received in chunks, installed on commit */
    proto_parser_t parser;
    imu_stream_t imu;
    service_io_t io;
    uint32_t window_cost;           /* ticks spent in the estimator since the last STEP */
    window_timing_t worst;          /* the most expensive window not yet reported in a TIMING */
    uint8_t worst_pending;          /* 0: no window since the last TIMING (or RESET) */
    uint32_t frames_bad_reported;
    uint32_t lost_reported;         /* the target's running total of lost bytes, last reported */
} service_t;

void service_init(service_t *s, const service_io_t *io);
/* Announce a (re)start to the host (STATUS BOOT). */
void service_boot(service_t *s);
/* Feed received bytes; answers are written through io.write. */
void service_feed(service_t *s, const uint8_t *data, size_t n);
/* The target's running total of bytes lost before the parser (a full receive buffer):
 * each new loss is counted as dropped and the host hears of it (STATUS RX_OVERFLOW). */
void service_note_lost(service_t *s, uint32_t lost_total);
/* One message received as a packet (no COBS, no CRC); answers go through io.packet. */
void service_feed_packet(service_t *s, const uint8_t *payload, size_t n);

#endif
