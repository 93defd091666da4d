/*
 * Wire protocol between the rig (host) and a board running the estimator
 * (docs/reference/protocol.md). No board dependencies: the firmware, the native program and
 * the fuzzer all link this file; rig/hil/protocol.py is its Python twin.
 *
 * Frame on the wire: COBS(payload || crc16_le(payload)) followed by one 0x00.
 * Payload: one message-type byte, then the fields of that message, little-endian,
 * at most PROTO_MAX_PAYLOAD bytes (one Crazyflie CRTP app-channel packet).
 * CRC: CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF).
 */
#ifndef UWB_RIG_PROTOCOL_H
#define UWB_RIG_PROTOCOL_H

#include <stddef.h>
#include <stdint.h>

#define PROTO_VERSION 5
#define PROTO_TRUST_FULL 65535   /* COUNTERS' correction trust: 65535 = the whole correction */
#define PROTO_MAX_PAYLOAD 30
#define PROTO_MAX_FRAME (PROTO_MAX_PAYLOAD + 2 + 2)   /* + CRC + COBS overhead byte + slack */
#define PROTO_MAX_ENCODED (PROTO_MAX_FRAME + 1)      /* + the 0x00 delimiter */

/* Scales of the compact encodings: IMU int16 per axis, packed TDOA int16. */
#define PROTO_ACCEL_LSB 0.005f    /* m/s^2 per count: +-163 m/s^2 (16 g) */
#define PROTO_GYRO_LSB 0.001f     /* rad/s per count: +-32.7 rad/s (1870 deg/s) */
#define PROTO_QUAT_LSB (1.0f / 32767.0f)
#define PROTO_TDOA_LSB 0.001f     /* m per count in packed TDOA items: +-32.767 m (others: MSG_TDOA) */

/* IMU samples travel as int16 absolute values in a key message, then as differences from
 * the previous sample, bit-packed with a width per axis (about 4.5 bytes a sample at
 * 1 kHz): the compactness is what lets QEMU's emulated USART (~13 kB/s) keep up with
 * real time. */
#define PROTO_IMU_AXES 6
#define PROTO_IMU_KEY_MAX_DELTAS 2     /* int8 delta samples after the absolute one in MSG_IMU */
#define PROTO_IMU_DELTA_HEADER 5       /* type, seq, 24-bit layout (see MSG_IMU_DELTA) */
#define PROTO_TDOA_ITEM 5              /* u16 dt_us, u8 id_a << 4 | id_b, i16 value */
#define PROTO_TDOA_PACK_MAX 5          /* packed TDOA items in one MSG_TDOA_PACK or MSG_STEP */

typedef enum {
    /* host -> board */
    MSG_HELLO = 0x01,        /* (empty) */
    MSG_PARAM = 0x02,        /* u8 index, f32 value (index order of est_params_t fields) */
    MSG_ANCHOR = 0x03,       /* u8 id, f32 pos[3], f32 quat[4] */
    MSG_NET_CHUNK = 0x04,    /* u16 offset, u8 data[<= 27] of a bias_net_t image */
    MSG_NET_COMMIT = 0x05,   /* u16 total size: check and install the received network */
    MSG_RESET = 0x06,        /* u32 t_us, f32 pos[3], i16 quat[4] (PROTO_QUAT_LSB) */
    MSG_IMU = 0x07,          /* key: u8 seq, i16 acc[3], i16 gyro[3], then 0..2 samples as i8 deltas[6];
                                samples are stamped at the window start (the estimator averages them) */
    MSG_TDOA = 0x08,         /* u16 dt_us, u8 id_a, u8 id_b, f32 distance difference (m): any value */
    MSG_STEP = 0x09,         /* u32 t_us, then 0..5 packed TDOA items: end of a 10 ms window,
                                answered by the estimate set */
    MSG_IMU_DELTA = 0x0A,    /* u8 seq, u24 layout (bits 3i..3i+2: width of axis i minus 1, bits 18..20:
                                samples minus 1), then the deltas from the previous sample, sample
                                by sample and axis by axis, two's complement, packed LSB first */
    MSG_TDOA_PACK = 0x0B,    /* 1..5 packed TDOA items (u16 dt_us, u8 ids, i16 value / PROTO_TDOA_LSB) */
    MSG_STEP_BRIEF = 0x0C,   /* as MSG_STEP, answered by ESTIMATE and ATTITUDE only: a link with few packets
                                a second asks for the counters and timing every N windows */
    MSG_ANCHORS_CLEAR = 0x0D, /* (empty): forget every anchor; sent before a flight's ANCHORs (version 4) */
    /* board -> host */
    MSG_HELLO_REPLY = 0x81,  /* u8 proto version, u8 api version, u8 timer unit, u8 max anchors,
                                u32 timer hz, u16 sizeof(bias_net_t), u8 capabilities */
    MSG_ACK = 0x82,          /* u8 acknowledged type, i8 status (0 ok, < 0 error code) */
    MSG_ESTIMATE = 0x83,     /* u32 t_us, f32 pos[3], f32 vel[3] */
    MSG_ATTITUDE = 0x84,     /* i16 quat[4] (x, y, z, w; PROTO_QUAT_LSB), f16 cov_diag[9]; follows ESTIMATE */
    MSG_COUNTERS = 0x85,     /* u32 steps, u32 accepted, u32 downweighted, u32 rejected, u16 resets,
                                u16 imu_gaps, u16 gated, u16 imu messages lost (delta without reference),
                                u16 share of the bias correction applied (PROTO_TRUST_FULL = all of it),
                                u16 TDOA of blocked anchors down-weighted (version 5; held at 65535) */
    MSG_TIMING = 0x86,       /* u32 t_us, u32 window, u32 predict, u32 tdoa_total, u32 tdoa_max, u8 n_tdoa
                                (costs in the timer unit of the hello reply) of the most expensive window
                                since the last TIMING (after brief STEPs, one of them); ends a STEP's answer */
    MSG_STATUS = 0x87        /* u8 code, u32 frames_ok, u32 frames_bad, u32 bytes_dropped */
} proto_msg_t;

/* Capability bits of the hello reply. */
#define PROTO_CAP_BIAS_NET 0x01u     /* takes a bias network (NET_CHUNK, NET_COMMIT) */
#define PROTO_CAP_BRIEF_STEP 0x02u   /* answers MSG_STEP_BRIEF */

typedef enum {
    PROTO_UNIT_NANOSECONDS = 0,
    PROTO_UNIT_CYCLES = 1,
    PROTO_UNIT_INSTRUCTIONS = 2
} proto_timer_unit_t;

typedef enum {
    PROTO_STATUS_BOOT = 1,       /* sent once after a (re)start: the host knows a reset happened */
    PROTO_STATUS_BAD_FRAME = 2,  /* a corrupt frame was dropped */
    PROTO_STATUS_BAD_MESSAGE = 3, /* a well-framed message with an unknown type or wrong length */
    PROTO_STATUS_RX_OVERFLOW = 4  /* the target's receive buffer was full: bytes lost before the parser */
} proto_status_code_t;

typedef enum {
    PROTO_ERR_LENGTH = -1,
    PROTO_ERR_RANGE = -2,
    PROTO_ERR_STATE = -3
} proto_error_t;

/* Stream decoder: feed bytes, get whole verified payloads. */
typedef struct {
    uint8_t buf[PROTO_MAX_FRAME];
    uint8_t len;
    uint8_t overflow;            /* current frame exceeded the buffer: drop until the next 0x00 */
    uint32_t frames_ok;
    uint32_t frames_bad;         /* bad COBS, bad CRC, too long or empty */
    uint32_t bytes_dropped;
} proto_parser_t;

uint16_t proto_crc16(const uint8_t *data, size_t n);

/* COBS: encode n (<= 254) bytes into out (n + 1 bytes); decode returns the length or -1. */
size_t proto_cobs_encode(const uint8_t *in, size_t n, uint8_t *out);
int proto_cobs_decode(const uint8_t *in, size_t n, uint8_t *out);

/* Build a frame (COBS + CRC + delimiter) from a payload; returns bytes written to out
 * (at most PROTO_MAX_ENCODED) or 0 when the payload is empty or too long. */
size_t proto_frame(const uint8_t *payload, size_t n, uint8_t out[PROTO_MAX_ENCODED]);

void proto_parser_init(proto_parser_t *p);
/* Feed one byte; returns the payload length (> 0) when a verified frame completed, with
 * the payload in `payload` (PROTO_MAX_PAYLOAD bytes), else 0. */
int proto_parser_feed(proto_parser_t *p, uint8_t byte, uint8_t payload[PROTO_MAX_PAYLOAD]);

/* Little-endian field access. */
void proto_put_u16(uint8_t *p, uint16_t v);
void proto_put_u32(uint8_t *p, uint32_t v);
void proto_put_f32(uint8_t *p, float v);
uint16_t proto_get_u16(const uint8_t *p);
uint32_t proto_get_u32(const uint8_t *p);
float proto_get_f32(const uint8_t *p);
int16_t proto_quantize(float value, float lsb);
uint16_t proto_f16(float value);   /* IEEE half, round to nearest, saturating to inf */

#endif
