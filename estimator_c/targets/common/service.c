/* Message handling of the board service (see service.h and docs/reference/protocol.md). */
#include "service.h"

#include <string.h>

static void send(service_t *s, const uint8_t *payload, size_t n)
{
    if (s->io.packet) {
        s->io.packet(payload, n);
        return;
    }
    uint8_t frame[PROTO_MAX_ENCODED];
    const size_t len = proto_frame(payload, n, frame);
    if (len) s->io.write(frame, len);
}

static void send_ack(service_t *s, uint8_t type, int8_t status)
{
    const uint8_t m[3] = {MSG_ACK, type, (uint8_t)status};
    send(s, m, sizeof m);
}

static void send_status(service_t *s, uint8_t code)
{
    uint8_t m[14] = {MSG_STATUS, code};
    proto_put_u32(&m[2], s->parser.frames_ok);
    proto_put_u32(&m[6], s->parser.frames_bad);
    proto_put_u32(&m[10], s->parser.bytes_dropped);
    send(s, m, sizeof m);
}

static void send_hello(service_t *s)
{
    uint8_t m[12] = {MSG_HELLO_REPLY, PROTO_VERSION, EST_API_VERSION, s->io.timer_unit, EST_MAX_ANCHORS};
    proto_put_u32(&m[5], s->io.timer_hz);
    proto_put_u16(&m[9], (uint16_t)sizeof(bias_net_t));
    m[11] = PROTO_CAP_BIAS_NET | PROTO_CAP_BRIEF_STEP;
    send(s, m, sizeof m);
}

/* A HELLO starts a session: the link's counts (frames, losses) restart with it, so a
 * board that serves session after session reports each one's own (version 4). */
static void restart_link_counts(service_t *s)
{
    s->parser.frames_ok = s->parser.frames_bad = s->parser.bytes_dropped = 0;
    s->frames_bad_reported = 0;
}

static void send_estimate(service_t *s, const est_output_t *out)
{
    uint8_t m[PROTO_MAX_PAYLOAD] = {MSG_ESTIMATE};
    proto_put_u32(&m[1], out->t_us);
    for (int i = 0; i < 3; i++) {
        proto_put_f32(&m[5 + 4 * i], out->pos[i]);
        proto_put_f32(&m[17 + 4 * i], out->vel[i]);
    }
    send(s, m, 29);
    /* the attitude does not fit the 30 bytes above: it follows, with the covariance diagonal */
    uint8_t c[27] = {MSG_ATTITUDE};
    for (int i = 0; i < 4; i++) proto_put_u16(&c[1 + 2 * i], (uint16_t)proto_quantize(out->quat[i], PROTO_QUAT_LSB));
    for (int i = 0; i < EST_STATE_DIM; i++) proto_put_u16(&c[9 + 2 * i], proto_f16(out->cov_diag[i]));
    send(s, c, sizeof c);
}

static void send_counters(service_t *s, const est_output_t *out)
{
    uint8_t k[29] = {MSG_COUNTERS};
    proto_put_u32(&k[1], out->counters.steps);
    proto_put_u32(&k[5], out->counters.tdoa_accepted);
    proto_put_u32(&k[9], out->counters.tdoa_downweighted);
    proto_put_u32(&k[13], out->counters.tdoa_rejected);
    proto_put_u16(&k[17], (uint16_t)out->counters.resets);
    proto_put_u16(&k[19], (uint16_t)out->counters.imu_gaps);
    proto_put_u16(&k[21], (uint16_t)out->counters.rejected[EST_REJ_GATE]);
    proto_put_u16(&k[23], s->imu.lost);
    proto_put_u16(&k[25], (uint16_t)(est_correction_trust(&s->est) * (float)PROTO_TRUST_FULL + 0.5f));
    /* a u16 that holds, not wraps: a flight's count over 65535 is not read as a small one */
    const uint32_t weighted = out->counters.tdoa_anchor_weighted;
    proto_put_u16(&k[27], (uint16_t)(weighted < 0xffffu ? weighted : 0xffffu));
    send(s, k, 29);
}

static void send_timing(service_t *s, const window_timing_t *w)
{
    uint8_t m[22] = {MSG_TIMING};
    proto_put_u32(&m[1], w->t_us);
    proto_put_u32(&m[5], w->window);
    proto_put_u32(&m[9], w->predict);
    proto_put_u32(&m[13], w->tdoa_total);
    proto_put_u32(&m[17], w->tdoa_max);
    m[21] = w->n_tdoa;
    send(s, m, sizeof m);
}

/* Keep the window just ended if it is the most expensive one the host has not seen:
 * after brief STEPs the next TIMING still shows the worst window, so a budget check
 * misses nothing. */
static void note_window_cost(service_t *s, uint32_t t_us)
{
    const est_step_cost_t *c = &s->est.cost;
    if (s->worst_pending && s->window_cost <= s->worst.window) return;
    s->worst = (window_timing_t){.t_us = t_us, .window = s->window_cost, .predict = c->predict,
                                 .tdoa_total = c->tdoa_total, .tdoa_max = c->tdoa_max, .n_tdoa = c->n_tdoa};
    s->worst_pending = 1;
}

/* Every estimator call goes through here, so the window's cost is the sum of them all. */
static est_status_t handle(service_t *s, const est_event_t *ev, est_output_t *out)
{
    const uint32_t t0 = s->io.clock ? s->io.clock() : 0;
    const est_status_t status = est_handle_event(&s->est, ev, out);
    if (s->io.clock) s->window_cost += s->io.clock() - t0;
    return status;
}

/* One IMU sample (int16 counts) into the estimator, stamped at the window start. */
static void imu_sample(service_t *s, const int16_t q[PROTO_IMU_AXES])
{
    est_event_t acc = {.t_us = s->est.t_step_us, .kind = EST_EV_ACCEL};
    est_event_t gyro = {.t_us = s->est.t_step_us, .kind = EST_EV_GYRO};
    for (int i = 0; i < 3; i++) {
        acc.v[i] = (float)q[i] * PROTO_ACCEL_LSB;
        gyro.v[i] = (float)q[3 + i] * PROTO_GYRO_LSB;
    }
    handle(s, &acc, NULL);
    handle(s, &gyro, NULL);
}

/* Samples given as int8 differences, each from the one before. */
static void imu_deltas(service_t *s, const uint8_t *d, int n_samples)
{
    for (int k = 0; k < n_samples; k++, d += PROTO_IMU_AXES) {
        for (int i = 0; i < PROTO_IMU_AXES; i++) s->imu.last[i] = (int16_t)(s->imu.last[i] + (int8_t)d[i]);
        imu_sample(s, s->imu.last);
    }
}

static void on_imu_key(service_t *s, const uint8_t *m, int n)
{
    for (int i = 0; i < PROTO_IMU_AXES; i++) s->imu.last[i] = (int16_t)proto_get_u16(&m[2 + 2 * i]);
    s->imu.valid = 1;
    s->imu.next_seq = (uint8_t)(m[1] + 1);
    imu_sample(s, s->imu.last);
    imu_deltas(s, &m[14], (n - 14) / PROTO_IMU_AXES);
}

/* Bits [*bit, *bit + width) of `data`, LSB first, as a two's-complement number. */
static int32_t take_bits(const uint8_t *data, uint32_t *bit, uint8_t width)
{
    uint32_t v = 0;
    for (uint8_t k = 0; k < width; k++, (*bit)++) v |= (uint32_t)((data[*bit >> 3] >> (*bit & 7u)) & 1u) << k;
    return (v & (1u << (width - 1))) ? (int32_t)v - (int32_t)(1u << width) : (int32_t)v;
}

/* Header of a packed delta message: widths of the six axes and the sample count. */
static int delta_layout(const uint8_t *m, uint8_t width[PROTO_IMU_AXES], int *n_samples)
{
    const uint32_t h = (uint32_t)m[2] | ((uint32_t)m[3] << 8) | ((uint32_t)m[4] << 16);
    int bits = 0;
    for (int i = 0; i < PROTO_IMU_AXES; i++) {
        width[i] = (uint8_t)(((h >> (3 * i)) & 7u) + 1u);
        bits += width[i];
    }
    *n_samples = (int)((h >> 18) & 7u) + 1;
    return PROTO_IMU_DELTA_HEADER + (*n_samples * bits + 7) / 8;
}

/* A delta message is only meaningful right after its predecessor: after a lost frame
 * the stream waits for the next key message (the host sends one regularly). */
static void on_imu_delta(service_t *s, const uint8_t *m, int n)
{
    uint8_t width[PROTO_IMU_AXES];
    int n_samples;
    if (delta_layout(m, width, &n_samples) != n) {
        send_status(s, PROTO_STATUS_BAD_MESSAGE);
        return;
    }
    if (!s->imu.valid || m[1] != s->imu.next_seq) {
        s->imu.valid = 0;
        s->imu.lost++;
        return;
    }
    s->imu.next_seq++;
    uint32_t bit = 0;
    for (int k = 0; k < n_samples; k++) {
        for (int i = 0; i < PROTO_IMU_AXES; i++)
            s->imu.last[i] = (int16_t)(s->imu.last[i] + take_bits(&m[PROTO_IMU_DELTA_HEADER], &bit, width[i]));
        imu_sample(s, s->imu.last);
    }
}

static void on_tdoa(service_t *s, const uint8_t *m)
{
    est_event_t ev = {.t_us = s->est.t_step_us + proto_get_u16(&m[1]), .kind = EST_EV_TDOA,
                      .id_a = m[3], .id_b = m[4]};
    ev.v[0] = proto_get_f32(&m[5]);
    handle(s, &ev, NULL);
}

static void packed_tdoa(service_t *s, const uint8_t *item, int n_items)
{
    for (int k = 0; k < n_items; k++, item += PROTO_TDOA_ITEM) {
        est_event_t ev = {.t_us = s->est.t_step_us + proto_get_u16(&item[0]), .kind = EST_EV_TDOA,
                          .id_a = (uint8_t)(item[2] >> 4), .id_b = (uint8_t)(item[2] & 0x0Fu)};
        ev.v[0] = (float)(int16_t)proto_get_u16(&item[3]) * PROTO_TDOA_LSB;
        handle(s, &ev, NULL);
    }
}

/* A full STEP is answered by ESTIMATE, ATTITUDE, COUNTERS and TIMING; a brief one by
 * ESTIMATE and ATTITUDE. */
static void on_step(service_t *s, const uint8_t *m, int n, int full)
{
    packed_tdoa(s, &m[5], (n - 5) / PROTO_TDOA_ITEM);
    est_event_t ev = {.t_us = proto_get_u32(&m[1]), .kind = EST_EV_STEP};
    est_output_t out;
    if (handle(s, &ev, &out) == EST_OUTPUT) {
        note_window_cost(s, out.t_us);
        send_estimate(s, &out);
        if (full) {
            send_counters(s, &out);
            send_timing(s, &s->worst);
            s->worst_pending = 0;
        }
    } else {
        send_ack(s, m[0], PROTO_ERR_STATE); /* a STEP back in time: rejected and counted */
    }
    s->window_cost = 0;
}

static int8_t on_param(service_t *s, const uint8_t *m)
{
    est_params_t *p = &s->est.params;
    float *floats[] = {&p->tdoa_std, &p->accel_noise, &p->gyro_noise, &p->position_noise, &p->velocity_noise,
                       &p->gate_m, &p->gm_state_c2, &p->gm_meas_c2};
    uint8_t *flags[] = {&p->robust, &p->irls_iterations, &p->use_bias_net, &p->thrust_only};
    float *late_floats[] = {&p->trust_prior_n, &p->anchor_bias_c};   /* after the flags, in the struct's order */
    const uint8_t index = m[1];
    const float value = proto_get_f32(&m[2]);
    const uint8_t n_floats = sizeof floats / sizeof floats[0], n_flags = sizeof flags / sizeof flags[0];
    const uint8_t n_late = sizeof late_floats / sizeof late_floats[0];
    if (!(value == value)) return PROTO_ERR_RANGE;
    if (index < n_floats) {
        *floats[index] = value;
    } else if (index < n_floats + n_flags) {
        if (!(value >= 0.0f && value <= 255.0f)) return PROTO_ERR_RANGE;
        *flags[index - n_floats] = (uint8_t)value;
    } else if (index < n_floats + n_flags + n_late) {
        *late_floats[index - n_floats - n_flags] = value;
    } else {
        return PROTO_ERR_RANGE;
    }
    return 0;
}

static int8_t on_net_chunk(service_t *s, const uint8_t *m, int n)
{
    const uint16_t offset = proto_get_u16(&m[1]);
    const size_t len = (size_t)n - 3;
    if ((size_t)offset + len > sizeof s->net) return PROTO_ERR_RANGE;
    est_set_bias_net(&s->est, NULL); /* never run a half-written network */
    memcpy((uint8_t *)&s->net + offset, &m[3], len);
    return 0;
}

static int8_t on_reset(service_t *s, const uint8_t *m)
{
    float pos[3], quat[4];
    for (int i = 0; i < 3; i++) pos[i] = proto_get_f32(&m[5 + 4 * i]);
    for (int i = 0; i < 4; i++) quat[i] = (float)(int16_t)proto_get_u16(&m[17 + 2 * i]) * PROTO_QUAT_LSB;
    est_reset(&s->est, proto_get_u32(&m[1]), pos, quat);
    s->window_cost = 0;
    s->worst_pending = 0;
    s->imu.valid = 0;   /* a new session starts with a key message, */
    s->imu.lost = 0;    /* and counts its own lost IMU messages */
    return 0;
}

static int whole(int n, int header, int item, int min_items, int max_items)
{
    const int body = n - header;
    return body >= 0 && body % item == 0 && body / item >= min_items && body / item <= max_items;
}

/* Expected payload length of each host message. */
static int length_ok(uint8_t type, int n)
{
    switch (type) {
    case MSG_HELLO: return n == 1;
    case MSG_ANCHORS_CLEAR: return n == 1;
    case MSG_PARAM: return n == 6;
    case MSG_ANCHOR: return n == 30;
    case MSG_NET_CHUNK: return n > 3;
    case MSG_NET_COMMIT: return n == 3;
    case MSG_RESET: return n == 25;
    case MSG_IMU: return whole(n, 14, PROTO_IMU_AXES, 0, PROTO_IMU_KEY_MAX_DELTAS);
    case MSG_IMU_DELTA: return n > PROTO_IMU_DELTA_HEADER; /* exact length checked against its header */
    case MSG_TDOA: return n == 9;
    case MSG_TDOA_PACK: return whole(n, 1, PROTO_TDOA_ITEM, 1, PROTO_TDOA_PACK_MAX);
    case MSG_STEP:
    case MSG_STEP_BRIEF: return whole(n, 5, PROTO_TDOA_ITEM, 0, PROTO_TDOA_PACK_MAX);
    default: return 0;
    }
}

static void dispatch(service_t *s, const uint8_t *m, int n)
{
    const uint8_t type = m[0];
    if (!length_ok(type, n)) {
        send_status(s, PROTO_STATUS_BAD_MESSAGE);
        return;
    }
    switch (type) {
    case MSG_HELLO: restart_link_counts(s); send_hello(s); break;
    case MSG_PARAM: send_ack(s, type, on_param(s, m)); break;
    case MSG_ANCHORS_CLEAR: est_clear_anchors(&s->est); send_ack(s, type, 0); break;
    case MSG_ANCHOR: {
        float pos[3], quat[4];
        for (int i = 0; i < 3; i++) pos[i] = proto_get_f32(&m[2 + 4 * i]);
        for (int i = 0; i < 4; i++) quat[i] = proto_get_f32(&m[14 + 4 * i]);
        send_ack(s, type, est_set_anchor(&s->est, m[1], pos, quat) ? PROTO_ERR_RANGE : 0);
        break;
    }
    case MSG_NET_CHUNK: send_ack(s, type, on_net_chunk(s, m, n)); break;
    case MSG_NET_COMMIT: {
        const int ok = proto_get_u16(&m[1]) == sizeof s->net;
        if (ok) est_set_bias_net(&s->est, &s->net);
        send_ack(s, type, ok ? 0 : PROTO_ERR_LENGTH);
        break;
    }
    case MSG_RESET: send_ack(s, type, on_reset(s, m)); break;
    case MSG_IMU: on_imu_key(s, m, n); break;
    case MSG_IMU_DELTA: on_imu_delta(s, m, n); break;
    case MSG_TDOA: on_tdoa(s, m); break;
    case MSG_TDOA_PACK: packed_tdoa(s, &m[1], (n - 1) / PROTO_TDOA_ITEM); break;
    case MSG_STEP: on_step(s, m, n, 1); break;
    case MSG_STEP_BRIEF: on_step(s, m, n, 0); break;
    default: break;
    }
}

void service_init(service_t *s, const service_io_t *io)
{
    memset(s, 0, sizeof *s);
    s->io = *io;
    est_init(&s->est, NULL);
    est_set_clock(&s->est, io->clock);
    proto_parser_init(&s->parser);
}

void service_boot(service_t *s)
{
    send_status(s, PROTO_STATUS_BOOT);
}

void service_feed(service_t *s, const uint8_t *data, size_t n)
{
    uint8_t payload[PROTO_MAX_PAYLOAD];
    for (size_t i = 0; i < n; i++) {
        const int len = proto_parser_feed(&s->parser, data[i], payload);
        if (len > 0) dispatch(s, payload, len);
        if (s->parser.frames_bad != s->frames_bad_reported) {
            s->frames_bad_reported = s->parser.frames_bad;
            send_status(s, PROTO_STATUS_BAD_FRAME);
        }
    }
}

void service_note_lost(service_t *s, uint32_t lost_total)
{
    if (lost_total == s->lost_reported) return;
    s->parser.bytes_dropped += lost_total - s->lost_reported;
    s->lost_reported = lost_total;
    send_status(s, PROTO_STATUS_RX_OVERFLOW);
}

void service_feed_packet(service_t *s, const uint8_t *payload, size_t n)
{
    if (n == 0 || n > PROTO_MAX_PAYLOAD) {
        s->parser.frames_bad++;
        s->frames_bad_reported = s->parser.frames_bad;
        send_status(s, PROTO_STATUS_BAD_FRAME);
        return;
    }
    s->parser.frames_ok++;
    dispatch(s, payload, (int)n);
}
