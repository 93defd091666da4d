/* Blocked-anchor weighting: each anchor's range bias tracked from the TDOA
 * innovations, and the measurements of an anchor whose bias is large made less
 * certain (docs/notebook/bias.md, session 83).
 *
 * An obstacle lengthens every link to the anchor it blocks by a few decimetres,
 * which the Geman-McClure weight of one measurement (c = 3 sigma) never sees; in
 * TDOA3 that anchor is paired with all the others. Each innovation is split
 * between its two anchors, bias[B] - bias[A], by a recursive least-squares step
 * per anchor that forgets over EST_ANCHOR_BIAS_WINDOW_S; the biases are kept
 * summing to zero over the anchors heard. The tracked biases only weight the
 * update, never correct it: they are estimated against the state they would
 * correct, and as states of the filter they made it worse (session 55). */
#include <math.h>

#include "ekf_core.h"

static int tracking(const estimator_t *est)
{
    return est->params.anchor_bias_c > 0.0f;
}

/* Forget with the time since the last STEP, and keep the biases summing to zero. */
void anchor_bias_forget(estimator_t *est, float dt)
{
    if (!tracking(est)) return;
    est_anchor_bias_t *ab = &est->anchor_bias;
    const float keep = expf(-dt / EST_ANCHOR_BIAS_WINDOW_S);
    float sum = 0.0f;
    int heard = 0;
    for (int k = 0; k < EST_MAX_ANCHORS; k++) {
        if (ab->n[k] <= 0.0f) continue;
        ab->n[k] *= keep;
        sum += ab->bias[k];
        heard++;
    }
    if (heard == 0) return;
    const float mean = sum / (float)heard;
    for (int k = 0; k < EST_MAX_ANCHORS; k++)
        if (ab->n[k] > 0.0f) ab->bias[k] -= mean;
}

/* The weight of a measurement between anchors a and b, in (0, 1]: the product of
 * the Geman-McClure weights of their biases at scale anchor_bias_c. */
float anchor_bias_weight(const estimator_t *est, uint8_t a, uint8_t b)
{
    if (!tracking(est)) return 1.0f;
    const float inv_c = 1.0f / est->params.anchor_bias_c;
    return gm_weight(est->anchor_bias.bias[a] * inv_c, 1.0f) * gm_weight(est->anchor_bias.bias[b] * inv_c, 1.0f);
}

/* One innovation (measured - predicted, after the correction) split between its
 * anchors; an outlier counts for as little as the robust update lets it. */
void anchor_bias_observe(estimator_t *est, uint8_t a, uint8_t b, float innovation)
{
    if (!tracking(est) || !isfinite(innovation)) return;
    est_anchor_bias_t *ab = &est->anchor_bias;
    const float w = gm_weight(innovation / est->params.tdoa_std, est->params.gm_meas_c2);
    const float e = innovation - (ab->bias[b] - ab->bias[a]);
    ab->n[a] += w;
    ab->n[b] += w;
    ab->bias[b] += w * e / (ab->n[b] + EST_ANCHOR_BIAS_PRIOR_N);
    ab->bias[a] -= w * e / (ab->n[a] + EST_ANCHOR_BIAS_PRIOR_N);
}
