/* Board-independent glue: parameters, anchors, input validation, IMU averaging
 * over each 10 ms window, the STEP that predicts and applies queued TDOA, and
 * divergence detection with reset. */
#include <math.h>
#include <string.h>

#include "ekf_core.h"

void est_default_params(est_params_t *p)
{
    p->tdoa_std = 0.4f;        /* above the robust std of real TDOA errors: bias is not white */
    p->accel_noise = 0.5f;
    p->gyro_noise = 0.1f;
    p->position_noise = 0.0f;
    p->velocity_noise = 0.0f;
    p->gate_m = 1.5f;
    p->gm_state_c2 = 2.25f;   /* c = 1.5 sigma on the whitened prior error */
    p->gm_meas_c2 = 9.0f;     /* c = 3 sigma on the measurement error */
    p->robust = 1;
    p->irls_iterations = 2;
    p->use_bias_net = 1;
    p->thrust_only = 1;
    p->trust_prior_n = EST_TRUST_PRIOR_N;  /* share of the correction a flight supports */
    p->anchor_bias_c = EST_ANCHOR_BIAS_C;  /* blocked-anchor weighting */
}

void est_init(estimator_t *est, const est_params_t *params)
{
    memset(est, 0, sizeof *est);
    if (params)
        est->params = *params;
    else
        est_default_params(&est->params);
    est->quat[3] = 1.0f;
    quat_to_rot(est->quat, est->rot);
}

float est_correction_trust(const estimator_t *est)
{
    return tdoa_trust_weight(est);
}

void est_clear_anchors(estimator_t *est)
{
    for (int k = 0; k < EST_MAX_ANCHORS; k++) est->anchors[k].valid = 0;
}

int est_set_anchor(estimator_t *est, uint8_t id, const float pos[3], const float quat[4])
{
    if (id >= EST_MAX_ANCHORS) return -1;
    est_anchor_t *a = &est->anchors[id];
    float n = 0;
    for (int i = 0; i < 4; i++) n += quat[i] * quat[i];
    for (int i = 0; i < 3; i++)
        if (!isfinite(pos[i])) return -1;
    if (!(n > 0.5f && n < 1.5f)) return -1;
    n = 1.0f / sqrtf(n);
    for (int i = 0; i < 3; i++) a->pos[i] = pos[i];
    for (int i = 0; i < 4; i++) a->quat[i] = quat[i] * n;
    quat_to_rot(a->quat, a->rot);
    a->valid = 1;
    return 0;
}

void est_set_bias_net(estimator_t *est, const bias_net_t *net)
{
    est->net = net;
}

static void reset_covariance(estimator_t *est)
{
    memset(est->P, 0, sizeof est->P);
    for (int i = 0; i < 3; i++) {
        est->P[EST_X + i][EST_X + i] = EST_INIT_POS_STD * EST_INIT_POS_STD;
        est->P[EST_VX + i][EST_VX + i] = EST_INIT_VEL_STD * EST_INIT_VEL_STD;
        est->P[EST_ATT + i][EST_ATT + i] = EST_INIT_ATT_STD * EST_INIT_ATT_STD;
    }
}

/* The filter restarted at a pose: state, covariance, IMU sums and queue (what a
 * divergence reset and the start of a flight share). */
static void restart_filter(estimator_t *est, uint32_t t_us, const float pos[3], const float quat[4])
{
    for (int i = 0; i < 3; i++) {
        est->pos[i] = pos[i];
        est->vel[i] = 0.0f;
    }
    if (quat) {
        for (int i = 0; i < 4; i++) est->quat[i] = quat[i];
    } else {
        est->quat[0] = est->quat[1] = est->quat[2] = 0.0f;
        est->quat[3] = 1.0f;
    }
    quat_to_rot(est->quat, est->rot);
    reset_covariance(est);
    memset(est->acc_sum, 0, sizeof est->acc_sum);
    memset(est->gyro_sum, 0, sizeof est->gyro_sum);
    est->acc_n = est->gyro_n = 0;
    est->acc_last[0] = est->acc_last[1] = 0.0f;
    est->acc_last[2] = EST_GRAVITY;
    memset(est->gyro_last, 0, sizeof est->gyro_last);
    est->queue_n = 0;
    memset(&est->anchor_bias, 0, sizeof est->anchor_bias);
    est->t_step_us = t_us;
    est->started = 1;
}

void est_reset(estimator_t *est, uint32_t t_us, const float pos[3], const float quat[4])
{
    restart_filter(est, t_us, pos, quat);
    memset(&est->trust, 0, sizeof est->trust);        /* a new flight: its own evidence only, */
    memset(&est->counters, 0, sizeof est->counters);  /* and its own counts */
}

/* Divergence reset: restart at the last finite position pulled inside the anchors'
 * bounding box, at rest, level, with the initial covariance. */
static void reset_after_divergence(estimator_t *est)
{
    float lo[3] = {1e9f, 1e9f, 1e9f}, hi[3] = {-1e9f, -1e9f, -1e9f};
    for (int k = 0; k < EST_MAX_ANCHORS; k++) {
        if (!est->anchors[k].valid) continue;
        for (int i = 0; i < 3; i++) {
            lo[i] = fminf(lo[i], est->anchors[k].pos[i]);
            hi[i] = fmaxf(hi[i], est->anchors[k].pos[i]);
        }
    }
    float pos[3];
    for (int i = 0; i < 3; i++) {
        float p = isfinite(est->pos[i]) ? est->pos[i] : 0.5f * (lo[i] + hi[i]);
        if (lo[i] <= hi[i]) p = fminf(fmaxf(p, lo[i]), hi[i]);
        pos[i] = p;
    }
    /* the same flight: what it showed still holds, and its counts go on */
    restart_filter(est, est->t_step_us, pos, NULL);
    est->counters.resets++;
}

static int all_finite(const float *v, int n)
{
    for (int i = 0; i < n; i++)
        if (!isfinite(v[i])) return 0;
    return 1;
}

static est_status_t reject(estimator_t *est, est_reject_reason_t why)
{
    est->counters.rejected[why]++;
    return EST_REJECTED;
}

static est_status_t queue_tdoa(estimator_t *est, const est_event_t *ev)
{
    if (!isfinite(ev->v[0])) return reject(est, EST_REJ_NONFINITE);
    if (ev->id_a >= EST_MAX_ANCHORS || ev->id_b >= EST_MAX_ANCHORS || !est->anchors[ev->id_a].valid
        || !est->anchors[ev->id_b].valid)
        return reject(est, EST_REJ_UNKNOWN_ANCHOR);
    if (ev->id_a == ev->id_b) return reject(est, EST_REJ_SAME_ANCHOR);
    const float *a = est->anchors[ev->id_a].pos, *b = est->anchors[ev->id_b].pos;
    const float dx = a[0] - b[0], dy = a[1] - b[1], dz = a[2] - b[2];
    if (fabsf(ev->v[0]) > sqrtf(dx * dx + dy * dy + dz * dz)) return reject(est, EST_REJ_EXCEEDS_BASELINE);
    if (est->queue_n >= EST_TDOA_QUEUE) return reject(est, EST_REJ_QUEUE_FULL);
    est_tdoa_t *m = &est->queue[est->queue_n++];
    m->t_us = ev->t_us;
    m->value = ev->v[0];
    m->id_a = ev->id_a;
    m->id_b = ev->id_b;
    return EST_OK;
}

static est_status_t add_imu(estimator_t *est, const est_event_t *ev)
{
    if (!all_finite(ev->v, 3)) return reject(est, EST_REJ_NONFINITE);
    float *sum = ev->kind == EST_EV_ACCEL ? est->acc_sum : est->gyro_sum;
    uint16_t *n = ev->kind == EST_EV_ACCEL ? &est->acc_n : &est->gyro_n;
    if (*n == UINT16_MAX) return EST_OK;  /* a window that long is a gap anyway */
    for (int i = 0; i < 3; i++) sum[i] += ev->v[i];
    (*n)++;
    est->counters.imu_samples++;
    return EST_OK;
}

/* Window average, or the previous one held over a gap. */
static void window_average(float sum[3], uint16_t *n, float last[3])
{
    if (*n > 0) {
        const float inv = 1.0f / (float)*n;
        for (int i = 0; i < 3; i++) last[i] = sum[i] * inv;
    }
    sum[0] = sum[1] = sum[2] = 0.0f;
    *n = 0;
}

void est_set_clock(estimator_t *est, est_clock_t clock)
{
    est->clock = clock;
}

static uint32_t ticks(const estimator_t *est)
{
    return est->clock ? est->clock() : 0u;
}

static void apply_queued_tdoa(estimator_t *est)
{
    est->cost.tdoa_total = est->cost.tdoa_max = 0;
    est->cost.n_tdoa = est->queue_n;
    for (int k = 0; k < est->queue_n; k++) {
        const uint32_t t0 = ticks(est);
        tdoa_update(est, &est->queue[k]);
        const uint32_t cost = ticks(est) - t0;
        est->cost.tdoa_total += cost;
        if (cost > est->cost.tdoa_max) est->cost.tdoa_max = cost;
    }
    est->queue_n = 0;
}

static void step(estimator_t *est, uint32_t t_us)
{
    const uint32_t t_predict = ticks(est);
    float dt = (float)(uint32_t)(t_us - est->t_step_us) * 1e-6f;
    est->t_step_us = t_us;
    if (est->acc_n == 0 || est->gyro_n == 0) est->counters.imu_gaps++;
    window_average(est->acc_sum, &est->acc_n, est->acc_last);
    window_average(est->gyro_sum, &est->gyro_n, est->gyro_last);
    if (dt > EST_MAX_DT) {
        /* A long gap: only the uncertainty grows; integrating stale IMU would mislead. */
        ekf_grow_uncertainty(est, dt);
        ekf_condition_covariance(est);
    } else if (dt > 0.0f) {
        float acc[3] = {est->acc_last[0], est->acc_last[1], est->acc_last[2]};
        if (est->params.thrust_only) acc[0] = acc[1] = 0.0f;
        ekf_predict(est, acc, est->gyro_last, dt);
    }
    est->cost.predict = ticks(est) - t_predict;
    anchor_bias_step(est, dt);
    apply_queued_tdoa(est);
    est->counters.steps++;
    if (ekf_is_diverged(est)) reset_after_divergence(est);
}

est_status_t est_handle_event(estimator_t *est, const est_event_t *ev, est_output_t *out)
{
    if (!est->started) {
        const float origin[3] = {0.0f, 0.0f, 0.0f};
        est_reset(est, ev->t_us, origin, NULL);
    }
    /* Signed difference: anything before the last STEP is late (wrap-safe for 71 min). */
    if ((int32_t)(ev->t_us - est->t_step_us) < 0) return reject(est, EST_REJ_TIME_BACKWARDS);
    switch (ev->kind) {
    case EST_EV_ACCEL:
    case EST_EV_GYRO:
        return add_imu(est, ev);
    case EST_EV_TDOA:
        return queue_tdoa(est, ev);
    case EST_EV_STEP:
        step(est, ev->t_us);
        if (out) est_get_output(est, out);
        return EST_OUTPUT;
    default:
        return reject(est, EST_REJ_BAD_KIND);
    }
}

void est_get_output(const estimator_t *est, est_output_t *out)
{
    out->t_us = est->t_step_us;
    memcpy(out->pos, est->pos, sizeof out->pos);
    memcpy(out->vel, est->vel, sizeof out->vel);
    memcpy(out->quat, est->quat, sizeof out->quat);
    for (int i = 0; i < EST_STATE_DIM; i++) out->cov_diag[i] = est->P[i][i];
    out->counters = est->counters;
}
