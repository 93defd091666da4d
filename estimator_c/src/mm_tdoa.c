/* TDOA measurement model: h(p) = |p - b| - |p - a|, its gradient, and the
 * measurement step that picks the plain or the robust update. */
#include <math.h>

#include "ekf_core.h"

/* Returns h(pos); grad = dh/dp = (p - b)/|p - b| - (p - a)/|p - a|. */
float tdoa_predict(const float pos[3], const float a[3], const float b[3], float grad[3])
{
    float da[3], db[3];
    for (int i = 0; i < 3; i++) {
        da[i] = pos[i] - a[i];
        db[i] = pos[i] - b[i];
    }
    const float ra = sqrtf(da[0] * da[0] + da[1] * da[1] + da[2] * da[2]);
    const float rb = sqrtf(db[0] * db[0] + db[1] * db[1] + db[2] * db[2]);
    /* The tag on an antenna makes the model singular; a millimetre floor keeps it finite. */
    const float ia = 1.0f / fmaxf(ra, 1e-3f), ib = 1.0f / fmaxf(rb, 1e-3f);
    for (int i = 0; i < 3; i++) grad[i] = db[i] * ib - da[i] * ia;
    return rb - ra;
}

/* G P G^T + sigma^2 for a Jacobian G nonzero on position only. */
static float innovation_variance(const estimator_t *est, const float grad[3])
{
    float s = est->params.tdoa_std * est->params.tdoa_std;
    for (int i = 0; i < 3; i++)
        s += grad[i] * (est->P[i][0] * grad[0] + est->P[i][1] * grad[1] + est->P[i][2] * grad[2]);
    return s;
}

/* Plain EKF update with a scalar measurement whose Jacobian is nonzero on position only. */
void tdoa_update_plain(estimator_t *est, float innovation, const float grad[3])
{
    float PG[EST_STATE_DIM];
    for (int i = 0; i < EST_STATE_DIM; i++)
        PG[i] = est->P[i][0] * grad[0] + est->P[i][1] * grad[1] + est->P[i][2] * grad[2];
    const float s = grad[0] * PG[0] + grad[1] * PG[1] + grad[2] * PG[2]
                    + est->params.tdoa_std * est->params.tdoa_std;
    const float inv_s = 1.0f / s;
    float dx[EST_STATE_DIM];
    for (int i = 0; i < EST_STATE_DIM; i++) dx[i] = PG[i] * inv_s * innovation;
    /* P <- P - K (G P) = P - PG PG^T / s  (rank one, stays symmetric) */
    for (int i = 0; i < EST_STATE_DIM; i++)
        for (int j = 0; j < EST_STATE_DIM; j++) est->P[i][j] -= PG[i] * PG[j] * inv_s;
    ekf_apply_error(est, dx);
}

static void count_weight(estimator_t *est, float weight)
{
    if (weight >= EST_WEIGHT_ACCEPTED)
        est->counters.tdoa_accepted++;
    else if (weight >= EST_WEIGHT_REJECTED)
        est->counters.tdoa_downweighted++;
    else
        est->counters.tdoa_rejected++;
}

void tdoa_update(estimator_t *est, const est_tdoa_t *m)
{
    const est_anchor_t *a = &est->anchors[m->id_a];
    const est_anchor_t *b = &est->anchors[m->id_b];
    /* The measurement was taken up to one window before this STEP: compare it with the
     * position back then, p - v * age (a centimetre at flight speed, not negligible). */
    const float age = (float)(uint32_t)(est->t_step_us - m->t_us) * 1e-6f;
    float pos_then[3];
    for (int i = 0; i < 3; i++) pos_then[i] = est->pos[i] - est->vel[i] * age;
    float grad[3];
    const float predicted = tdoa_predict(pos_then, a->pos, b->pos, grad);
    float measured = m->value;
    if (est->params.use_bias_net && est->net) {
        float features[BN_INPUTS];
        bn_features(pos_then, est->rot, a->pos, a->rot, b->pos, b->rot, features);
        measured -= bn_predict(est->net, features);
    }
    const float innovation = measured - predicted;

    /* Hard gate: an innovation both large in metres and many sigmas out is not this
     * flight's geometry (multipath far beyond what the robust cost should even see). */
    if (fabsf(innovation) > est->params.gate_m
        && innovation * innovation > EST_GATE_SIGMAS * EST_GATE_SIGMAS * innovation_variance(est, grad)) {
        est->counters.rejected[EST_REJ_GATE]++;
        est->counters.tdoa_rejected++;
        return;
    }
    if (est->params.robust) {
        count_weight(est, tdoa_update_robust(est, innovation, grad));
    } else {
        tdoa_update_plain(est, innovation, grad);
        est->counters.tdoa_accepted++;
    }
    ekf_condition_covariance(est);
}
