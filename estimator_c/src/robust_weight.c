/* Robust weighting: the Geman-McClure weight and the Cholesky factor used to
 * whiten the prior state error (paper Section V.A). */
#include <math.h>

#include "ekf_core.h"

/* Geman-McClure: rho(e) = (c2/2) e^2 / (c2 + e^2), so w(e) = rho'(e)/e = (c2 / (c2 + e^2))^2.
 * w(0) = 1 (a plain least-squares weight); w falls off as e^-4 for |e| >> c. */
float gm_weight(float e, float c2)
{
    const float r = c2 / (c2 + e * e);
    return r * r;
}

/* A = L L^T for symmetric positive definite A; returns 0 on success, -1 if A is
 * not positive definite (L is then unusable). Only the lower triangle is written. */
int cholesky_lower(const float A[EST_STATE_DIM][EST_STATE_DIM], float L[EST_STATE_DIM][EST_STATE_DIM])
{
    for (int j = 0; j < EST_STATE_DIM; j++) {
        float d = A[j][j];
        for (int k = 0; k < j; k++) d -= L[j][k] * L[j][k];
        if (!(d > 0.0f)) return -1;
        const float ljj = sqrtf(d);
        L[j][j] = ljj;
        const float inv = 1.0f / ljj;
        for (int i = j + 1; i < EST_STATE_DIM; i++) {
            float s = A[i][j];
            for (int k = 0; k < j; k++) s -= L[i][k] * L[j][k];
            L[i][j] = s * inv;
        }
    }
    return 0;
}
