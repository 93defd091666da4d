/* TDOA measurement model: h(p) = |p - b| - |p - a|, its gradient, and the
 * measurement step that picks the plain or the robust update (both in the core:
 * ekf_scalar_update and ekf_robust_scalar_update). */
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

static void count_weight(estimator_t *est, float weight)
{
    if (weight >= EST_WEIGHT_ACCEPTED)
        est->counters.tdoa_accepted++;
    else if (weight >= EST_WEIGHT_REJECTED)
        est->counters.tdoa_downweighted++;
    else
        est->counters.tdoa_rejected++;
}

/* The share of the correction applied, in [0, 1]: the regression slope of the
 * uncorrected innovations on the corrections, pulled to 1 by a prior of
 * trust_prior_n pseudo-measurements of the flight's mean c^2. */
float tdoa_trust_weight(const estimator_t *est)
{
    const est_trust_t *t = &est->trust;
    const float n0 = est->params.trust_prior_n;
    if (n0 < 0.0f || t->n <= 0.0f) return 1.0f;
    const float prior = n0 * t->s_cc / t->n;
    const float w = (t->s_cv + prior) / (t->s_cc + prior);
    return isfinite(w) ? fminf(fmaxf(w, 0.0f), 1.0f) : 1.0f;
}

static void observe_trust(estimator_t *est, float correction, float innovation_raw, float innovation)
{
    /* a state blown to inf or NaN (until its divergence reset) says nothing about the
     * correction, and one NaN in the sums would fix the trust for the rest of the flight */
    if (!isfinite(innovation_raw) || !isfinite(innovation)) return;
    const float e = innovation / est->params.tdoa_std;
    const float w = gm_weight(e, est->params.gm_meas_c2);
    est->trust.s_cc += w * correction * correction;
    est->trust.s_cv += w * correction * innovation_raw;
    est->trust.n += w;
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
    float correction = 0.0f;
    if (est->params.use_bias_net && est->net) {
        float features[BN_INPUTS];
        bn_features(pos_then, est->rot, a->pos, a->rot, b->pos, b->rot, features);
        correction = bn_predict(est->net, features, m->id_a, m->id_b);
        /* a damaged network (an upload's NaN or inf) refuses the measurement, never the state */
        if (!isfinite(correction)) {
            est->counters.rejected[EST_REJ_NONFINITE]++;
            return;
        }
    }
    const float innovation_raw = m->value - predicted;
    const float innovation = (m->value - tdoa_trust_weight(est) * correction) - predicted;

    /* Hard gate: an innovation both large in metres and many sigmas out is not this
     * flight's geometry (multipath far beyond what the robust cost should even see). */
    if (fabsf(innovation) > est->params.gate_m
        && innovation * innovation > EST_GATE_SIGMAS * EST_GATE_SIGMAS
                                       * ekf_innovation_variance(est, grad, est->params.tdoa_std)) {
        est->counters.rejected[EST_REJ_GATE]++;
        est->counters.tdoa_rejected++;
        return;
    }
    if (correction != 0.0f) observe_trust(est, correction, innovation_raw, innovation);
    /* weighted by the anchors' biases before this measurement adds to them */
    const float anchor_weight = anchor_bias_weight(est, m->id_a, m->id_b);
    if (anchor_weight < EST_WEIGHT_ACCEPTED) est->counters.tdoa_anchor_weighted++;
    const float std = est->params.tdoa_std / sqrtf(anchor_weight);
    anchor_bias_observe(est, m->id_a, m->id_b, innovation);
    if (est->params.robust) {
        count_weight(est, ekf_robust_scalar_update(est, grad, innovation, std));
    } else {
        ekf_scalar_update(est, grad, innovation, std);
        est->counters.tdoa_accepted++;
    }
    ekf_condition_covariance(est);
}
