/* M-estimation TDOA update (paper Section V.A): Geman-McClure cost on the
 * whitened prior error e_x = S^-1 (x - x_prior) (S: Cholesky factor of the prior
 * covariance) and on the measurement error e_d = (d - g(x)) / sigma, solved by
 * IRLS with a fixed number of iterations:
 *
 *   P~ = S W_x^-1 S^T,  s~2 = s2 / w(e_d),  K = P~ G^T (G P~ G^T + s~2)^-1,
 *   x = x_prior + K (d - g(x_prior)),       P = (I - K G) P~  (after the last).
 *
 * G is nonzero on the three position entries only, which the code exploits. */
#include <math.h>
#include <string.h>

#include "ekf_core.h"

#define N EST_STATE_DIM
/* Floor on the prior-error weights: caps how far one measurement can inflate P~. */
#define EST_MIN_STATE_WEIGHT 1e-3f

/* e = S^-1 dx by forward substitution. */
static void whiten(const float S[N][N], const float dx[N], float e[N])
{
    for (int i = 0; i < N; i++) {
        float v = dx[i];
        for (int k = 0; k < i; k++) v -= S[i][k] * e[k];
        e[i] = v / S[i][i];
    }
}

/* PG = P~ G^T = S D S^T G^T with D = diag(inv_w); G^T = (grad, 0...). */
static void reweighted_gain_column(const float S[N][N], const float inv_w[N], const float grad[3], float PG[N])
{
    /* u = D S^T G^T: S lower, so (S^T G^T)_k = sum_{i<3, i>=k} S[i][k] grad[i], zero for k >= 3 */
    float u[3];
    for (int k = 0; k < 3; k++) {
        float v = 0;
        for (int i = k; i < 3; i++) v += S[i][k] * grad[i];
        u[k] = v * inv_w[k];
    }
    for (int i = 0; i < N; i++) {
        const int kmax = i < 2 ? i : 2;
        float v = 0;
        for (int k = 0; k <= kmax; k++) v += S[i][k] * u[k];
        PG[i] = v;
    }
}

/* The robust counterpart of ekf_scalar_update for a measurement of noise `std`;
 * returns the final measurement weight. */
float ekf_robust_scalar_update(estimator_t *est, const float grad[3], float innovation, float std)
{
    const est_params_t *prm = &est->params;
    float S[N][N];
    memset(S, 0, sizeof S);
    if (cholesky_lower((const float (*)[N])est->P, S) != 0) {
        /* Not positive definite (numerically): fall back to the plain update this once. */
        ekf_scalar_update(est, grad, innovation, std);
        return 1.0f;
    }
    const float sigma2 = std * std;
    const float inv_sigma = 1.0f / std;
    float dx[N] = {0};
    float inv_w[N];
    float PG[N];
    float w_d = 1.0f, inv_s = 0.0f;
    const int iterations = prm->irls_iterations > 0 ? prm->irls_iterations : 1;

    for (int it = 0; it < iterations; it++) {
        float e[N];
        whiten((const float (*)[N])S, dx, e);
        for (int i = 0; i < N; i++) inv_w[i] = 1.0f / fmaxf(gm_weight(e[i], prm->gm_state_c2), EST_MIN_STATE_WEIGHT);
        /* residual of the linearised model at the current iterate */
        const float r = innovation - (grad[0] * dx[0] + grad[1] * dx[1] + grad[2] * dx[2]);
        w_d = gm_weight(r * inv_sigma, prm->gm_meas_c2);
        reweighted_gain_column((const float (*)[N])S, inv_w, grad, PG);
        const float s = grad[0] * PG[0] + grad[1] * PG[1] + grad[2] * PG[2] + sigma2 / w_d;
        inv_s = 1.0f / s;
        for (int i = 0; i < N; i++) dx[i] = PG[i] * inv_s * innovation;
    }

    /* Posterior covariance: P = P~ - PG PG^T / s with P~ = S D S^T of the last iteration. */
    for (int i = 0; i < N; i++) {
        for (int j = 0; j <= i; j++) {
            float v = 0;
            for (int k = 0; k <= j; k++) v += S[i][k] * inv_w[k] * S[j][k];
            v -= PG[i] * PG[j] * inv_s;
            est->P[i][j] = v;
            est->P[j][i] = v;
        }
    }
    ekf_apply_error(est, dx);
    return w_d;
}
