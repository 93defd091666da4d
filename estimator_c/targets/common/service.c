/* Message handling of the board service (see service.h and docs/protocol.md). */
#include "service.h"

#include <string.h>

static void send(service_t *s, const uint8_t *payload, size_t n)
{
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
    m[11] = 1; /* capabilities: bit 0 = bias network */
    send(s, m, sizeof m);
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
    uint8_t k[24] = {MSG_COUNTERS};
    proto_put_u32(&k[1], out->counters.steps);
    proto_put_u32(&k[5], out->counters.tdoa_accepted);
    proto_put_u32(&k[9], out->counters.tdoa_downweighted);
    proto_put_u32(&k[13], out->counters.tdoa_rejected);
    proto_put_u16(&k[17], (uint16_t)out->counters.resets);
    proto_put_u16(&k[19], (uint16_t)out->counters.imu_gaps);
    proto_put_u16(&k[21], (uint16_t)out->counters.rejected[EST_REJ_GATE]);
    send(s, k, 23);
}

static void send_timing(service_t *s, uint32_t t_us)
{
    const est_step_cost_t *c = &s->est.cost;
    uint8_t m[22] = {MSG_TIMING};
    proto_put_u32(&m[1], t_us);
    proto_put_u32(&m[5], s->window_cost);
    proto_put_u32(&m[9], c->predict);
    proto_put_u32(&m[13], c->tdoa_total);
    proto_put_u32(&m[17], c->tdoa_max);
    m[21] = c->n_tdoa;
    send(s, m, sizeof m);
}

/* Every estimator call goes through here, so the window's cost is the sum of them all. */
static est_status_t handle(service_t *s, const est_event_t *ev, est_output_t *out)
{
    const uint32_t t0 = s->io.clock ? s->io.clock() : 0;
    const est_status_t status = est_handle_event(&s->est, ev, out);
    if (s->io.clock) s->window_cost += s->io.clock() - t0;
    return status;
}

static void on_imu(service_t *s, const uint8_t *m, int n)
{
    for (int off = 1; off + 14 <= n; off += 14) {
        est_event_t acc = {.t_us = s->est.t_step_us + proto_get_u16(&m[off]), .kind = EST_EV_ACCEL};
        est_event_t gyro = {.t_us = acc.t_us, .kind = EST_EV_GYRO};
        for (int i = 0; i < 3; i++) {
            acc.v[i] = (float)(int16_t)proto_get_u16(&m[off + 2 + 2 * i]) * PROTO_ACCEL_LSB;
            gyro.v[i] = (float)(int16_t)proto_get_u16(&m[off + 8 + 2 * i]) * PROTO_GYRO_LSB;
        }
        handle(s, &acc, NULL);
        handle(s, &gyro, NULL);
    }
}

static void on_tdoa(service_t *s, const uint8_t *m)
{
    est_event_t ev = {.t_us = s->est.t_step_us + proto_get_u16(&m[1]), .kind = EST_EV_TDOA,
                      .id_a = m[3], .id_b = m[4]};
    ev.v[0] = proto_get_f32(&m[5]);
    handle(s, &ev, NULL);
}

static void on_step(service_t *s, const uint8_t *m)
{
    est_event_t ev = {.t_us = proto_get_u32(&m[1]), .kind = EST_EV_STEP};
    est_output_t out;
    if (handle(s, &ev, &out) == EST_OUTPUT) {
        send_estimate(s, &out);
        send_timing(s, out.t_us);
    } else {
        send_ack(s, MSG_STEP, PROTO_ERR_STATE); /* a STEP back in time: rejected and counted */
    }
    s->window_cost = 0;
}

static int8_t on_param(service_t *s, const uint8_t *m)
{
    est_params_t *p = &s->est.params;
    float *floats[] = {&p->tdoa_std, &p->accel_noise, &p->gyro_noise, &p->position_noise, &p->velocity_noise,
                       &p->gate_m, &p->gm_state_c2, &p->gm_meas_c2};
    uint8_t *flags[] = {&p->robust, &p->irls_iterations, &p->use_bias_net, &p->thrust_only};
    const uint8_t index = m[1];
    const float value = proto_get_f32(&m[2]);
    const uint8_t n_floats = sizeof floats / sizeof floats[0], n_flags = sizeof flags / sizeof flags[0];
    if (!(value == value)) return PROTO_ERR_RANGE;
    if (index < n_floats) {
        *floats[index] = value;
    } else if (index < n_floats + n_flags && value >= 0.0f && value <= 255.0f) {
        *flags[index - n_floats] = (uint8_t)value;
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
    return 0;
}

/* Expected payload length of each host message (IMU: one or two samples). */
static int length_ok(uint8_t type, int n)
{
    switch (type) {
    case MSG_HELLO: return n == 1;
    case MSG_PARAM: return n == 6;
    case MSG_ANCHOR: return n == 30;
    case MSG_NET_CHUNK: return n > 3;
    case MSG_NET_COMMIT: return n == 3;
    case MSG_RESET: return n == 25;
    case MSG_IMU: return n == 15 || n == 29;
    case MSG_TDOA: return n == 9;
    case MSG_STEP: return n == 5;
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
    case MSG_HELLO: send_hello(s); break;
    case MSG_PARAM: send_ack(s, type, on_param(s, m)); break;
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
    case MSG_IMU: on_imu(s, m, n); break;
    case MSG_TDOA: on_tdoa(s, m); break;
    case MSG_STEP: on_step(s, m); break;
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
