/* Blocked-anchor weighting: each anchor's range bias tracked from the TDOA
 * innovations, and the measurements of an anchor whose bias is large made less
 * certain (docs/notebook/bias.md, session 83).
 *
 * An obstacle lengthens every link to the anchor it blocks by a few decimetres,
 * which the Geman-McClure weight of one measurement (c = 3 sigma) never sees; in
 * TDOA3 that anchor is paired with all the others. Each innovation is split
 * between its two anchors, bias[B] - bias[A], by a recursive least-squares step
 * per anchor that forgets over EST_ANCHOR_BIAS_WINDOW_S. A position error dp reads
 * as a bias too, u_k . dp (u_k the unit vector from anchor k to the tag), so the
 * weight is decided by what of the biases no position error explains (`excess`),
 * and only for an anchor heard with EST_ANCHOR_BIAS_MIN_PARTNERS others, whose
 * bias is its own and not one pair's. The tracked biases only weight the update,
 * never correct it: as states of the filter they made it worse (session 55). */
#include <math.h>
#include <string.h>

#include "ekf_core.h"

#define FIT_DIM 4   /* excess: the fit of c + u_k . dp removed */

static int tracking(const estimator_t *est)
{
    return est->params.anchor_bias_c > 0.0f;
}

static int partner_count(const est_anchor_bias_t *ab, int k)
{
    uint32_t mask = (uint32_t)(ab->partners[k] | ab->partners_before[k]);
    int count = 0;
    for (; mask; mask &= mask - 1u) count++;
    return count;
}

/* Solve the FIT_DIM x FIT_DIM normal equations A x = r (A symmetric positive definite)
 * by Cholesky; returns -1 when A is singular (too few anchors, or all in a line). */
static int solve_fit(float A[FIT_DIM][FIT_DIM], const float r[FIT_DIM], float x[FIT_DIM])
{
    float L[FIT_DIM][FIT_DIM] = {{0}};
    for (int j = 0; j < FIT_DIM; j++) {
        float d = A[j][j];
        for (int k = 0; k < j; k++) d -= L[j][k] * L[j][k];
        if (!(d > 1e-6f)) return -1;
        L[j][j] = sqrtf(d);
        for (int i = j + 1; i < FIT_DIM; i++) {
            float s = A[i][j];
            for (int k = 0; k < j; k++) s -= L[i][k] * L[j][k];
            L[i][j] = s / L[j][j];
        }
    }
    float y[FIT_DIM];
    for (int i = 0; i < FIT_DIM; i++) {
        float s = r[i];
        for (int k = 0; k < i; k++) s -= L[i][k] * y[k];
        y[i] = s / L[i][i];
    }
    for (int i = FIT_DIM - 1; i >= 0; i--) {
        float s = y[i];
        for (int k = i + 1; k < FIT_DIM; k++) s -= L[k][i] * x[k];
        x[i] = s / L[i][i];
    }
    return 0;
}

static void fit_row(const estimator_t *est, int k, float row[FIT_DIM])
{
    float u[3];
    for (int i = 0; i < 3; i++) u[i] = est->pos[i] - est->anchors[k].pos[i];
    const float inv = 1.0f / fmaxf(sqrtf(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]), 1e-3f);
    row[0] = 1.0f;
    for (int i = 0; i < 3; i++) row[i + 1] = u[i] * inv;
}

static int heard(const estimator_t *est, int k)
{
    return est->anchor_bias.n[k] > 1.0f && est->anchors[k].valid;
}

/* excess = bias less its least-squares fit c + u_k . dp over the anchors heard. */
static void update_excess(estimator_t *est)
{
    est_anchor_bias_t *ab = &est->anchor_bias;
    float A[FIT_DIM][FIT_DIM] = {{0}}, r[FIT_DIM] = {0}, x[FIT_DIM], row[FIT_DIM];
    int count = 0;
    memset(ab->excess, 0, sizeof ab->excess);
    for (int k = 0; k < EST_MAX_ANCHORS; k++) {
        if (!heard(est, k)) continue;
        fit_row(est, k, row);
        for (int i = 0; i < FIT_DIM; i++) {
            r[i] += row[i] * ab->bias[k];
            for (int j = 0; j < FIT_DIM; j++) A[i][j] += row[i] * row[j];
        }
        count++;
    }
    if (count <= FIT_DIM || solve_fit(A, r, x) != 0) return;
    for (int k = 0; k < EST_MAX_ANCHORS; k++) {
        if (!heard(est, k)) continue;
        fit_row(est, k, row);
        ab->excess[k] = ab->bias[k] - (row[0] * x[0] + row[1] * x[1] + row[2] * x[2] + row[3] * x[3]);
    }
}

/* exp(-x) for x >= 0 to 1e-5 over a STEP (x <= 0.01), and falling to 0 over longer
 * gaps: a series keeps libm's expf, and its kilobyte and a half of flash, off the board. */
static float forgetting(float x)
{
    return 1.0f / (1.0f + x * (1.0f + x * (0.5f + x * (1.0f / 6.0f))));
}

/* At each STEP: forget with the time since the last one, keep the biases summing to
 * zero, roll the partner windows and find what no position error explains. */
void anchor_bias_step(estimator_t *est, float dt)
{
    if (!tracking(est)) return;
    est_anchor_bias_t *ab = &est->anchor_bias;
    const float keep = forgetting(dt / EST_ANCHOR_BIAS_WINDOW_S);
    float sum = 0.0f;
    int count = 0;
    for (int k = 0; k < EST_MAX_ANCHORS; k++) {
        if (ab->n[k] <= 0.0f) continue;
        ab->n[k] *= keep;
        sum += ab->bias[k];
        count++;
    }
    if (count > 0)
        for (int k = 0; k < EST_MAX_ANCHORS; k++)
            if (ab->n[k] > 0.0f) ab->bias[k] -= sum / (float)count;
    ab->window_s += dt;
    if (ab->window_s >= EST_ANCHOR_BIAS_WINDOW_S) {
        memcpy(ab->partners_before, ab->partners, sizeof ab->partners);
        memset(ab->partners, 0, sizeof ab->partners);
        ab->window_s = 0.0f;
    }
    update_excess(est);
}

/* One anchor's weight, in (0, 1]: the Geman-McClure weight of its excess bias at scale
 * anchor_bias_c once it has enough partners; 1 before, and with the weighting off. */
float anchor_bias_anchor_weight(const estimator_t *est, uint8_t k)
{
    const est_anchor_bias_t *ab = &est->anchor_bias;
    if (!tracking(est) || k >= EST_MAX_ANCHORS || partner_count(ab, k) < EST_ANCHOR_BIAS_MIN_PARTNERS) return 1.0f;
    return gm_weight(ab->excess[k] / est->params.anchor_bias_c, 1.0f);
}

/* The weight of a measurement between anchors a and b: the product of theirs. */
float anchor_bias_weight(const estimator_t *est, uint8_t a, uint8_t b)
{
    return anchor_bias_anchor_weight(est, a) * anchor_bias_anchor_weight(est, b);
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
    ab->partners[a] |= (uint16_t)(1u << b);
    ab->partners[b] |= (uint16_t)(1u << a);
}
