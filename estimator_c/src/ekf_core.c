/* State and prediction: the nominal state (position, velocity, attitude) is
 * propagated with the window-averaged IMU; the 9-dim error-state covariance with
 * the linearised dynamics (attitude error in the body frame, R_true = R exp([d]x)). */
#include <math.h>
#include <string.h>

#include "ekf_core.h"

void quat_to_rot(const float q[4], float r[3][3])
{
    const float x = q[0], y = q[1], z = q[2], w = q[3];
    r[0][0] = 1 - 2 * (y * y + z * z); r[0][1] = 2 * (x * y - z * w);     r[0][2] = 2 * (x * z + y * w);
    r[1][0] = 2 * (x * y + z * w);     r[1][1] = 1 - 2 * (x * x + z * z); r[1][2] = 2 * (y * z - x * w);
    r[2][0] = 2 * (x * z - y * w);     r[2][1] = 2 * (y * z + x * w);     r[2][2] = 1 - 2 * (x * x + y * y);
}

/* q <- q * exp(theta/2): rotate the body frame by the body-frame rotation vector theta.
 * sin and cos come from their Taylor series (exact to float precision for angles up
 * to 1 rad; larger rotations are applied in pieces), which keeps libm's sinf/cosf
 * and their kilobytes of reduction tables out of the firmware. */
static void quat_rotate_body(float q[4], const float theta[3])
{
    const float angle = sqrtf(theta[0] * theta[0] + theta[1] * theta[1] + theta[2] * theta[2]);
    const int pieces = angle > 1.0f ? (int)ceilf(angle) : 1;
    const float h = 0.5f * angle / (float)pieces, h2 = h * h;   /* half angle of one piece */
    const float c = 1.0f - h2 / 2 * (1.0f - h2 / 12 * (1.0f - h2 / 30 * (1.0f - h2 / 56)));
    /* sin(h)/angle_piece = (sin(h)/h) / 2 */
    const float s = 0.5f * (1.0f - h2 / 6 * (1.0f - h2 / 20 * (1.0f - h2 / 42 * (1.0f - h2 / 72))));
    const float dx = theta[0] * s / (float)pieces, dy = theta[1] * s / (float)pieces,
                dz = theta[2] * s / (float)pieces;
    for (int k = 0; k < pieces; k++) {
        const float x = q[0], y = q[1], z = q[2], w = q[3];
        q[0] = w * dx + x * c + y * dz - z * dy;
        q[1] = w * dy - x * dz + y * c + z * dx;
        q[2] = w * dz + x * dy - y * dx + z * c;
        q[3] = w * c - x * dx - y * dy - z * dz;
    }
    const float n = 1.0f / sqrtf(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    for (int i = 0; i < 4; i++) q[i] *= n;
}

void ekf_grow_uncertainty(estimator_t *est, float dt)
{
    const est_params_t *p = &est->params;
    const float qp = p->position_noise * p->position_noise * dt;
    const float qv = (p->accel_noise * p->accel_noise * dt + p->velocity_noise * p->velocity_noise) * dt;
    const float qa = p->gyro_noise * p->gyro_noise * dt * dt;
    for (int i = 0; i < 3; i++) {
        est->P[EST_X + i][EST_X + i] += qp;
        est->P[EST_VX + i][EST_VX + i] += qv;
        est->P[EST_ATT + i][EST_ATT + i] += qa;
    }
}

/* The error-state transition
 *   F = [ I  I*dt  0        ]
 *       [ 0  I    -R[a]x dt ]
 *       [ 0  0     I-[w]x dt]
 * as its two nontrivial blocks A = -R[a]x dt and W = I - [w]x dt (tested against
 * finite differences of the nominal propagation in tests/test_core.c). */
void ekf_transition_blocks(const estimator_t *est, const float acc[3], const float gyro[3], float dt,
                           float A[3][3], float W[3][3])
{
    const float ax[3][3] = {{0, -acc[2], acc[1]}, {acc[2], 0, -acc[0]}, {-acc[1], acc[0], 0}};
    for (int i = 0; i < 3; i++) {
        for (int j = 0; j < 3; j++) {
            float s = 0;
            for (int k = 0; k < 3; k++) s += est->rot[i][k] * ax[k][j];
            A[i][j] = -s * dt;
        }
    }
    const float wdt[3] = {gyro[0] * dt, gyro[1] * dt, gyro[2] * dt};
    W[0][0] = 1;        W[0][1] = wdt[2];  W[0][2] = -wdt[1];
    W[1][0] = -wdt[2];  W[1][1] = 1;       W[1][2] = wdt[0];
    W[2][0] = wdt[1];   W[2][1] = -wdt[0]; W[2][2] = 1;
}

/* P <- F P F^T, written out block-wise (F is sparse; a dense 9x9x9 product would
 * waste the budget). */
static void propagate_covariance(estimator_t *est, const float acc[3], const float gyro[3], float dt)
{
    float (*P)[EST_STATE_DIM] = est->P;
    float A[3][3];   /* -R [a]x dt */
    float W[3][3];   /* I - [w]x dt */
    ekf_transition_blocks(est, acc, gyro, dt, A, W);

    /* T = F P (row blocks), then P = T F^T (column blocks). */
    float T[EST_STATE_DIM][EST_STATE_DIM];
    for (int c = 0; c < EST_STATE_DIM; c++) {
        for (int i = 0; i < 3; i++) {
            T[EST_X + i][c] = P[EST_X + i][c] + dt * P[EST_VX + i][c];
            float v = P[EST_VX + i][c], a = 0;
            for (int k = 0; k < 3; k++) {
                v += A[i][k] * P[EST_ATT + k][c];
                a += W[i][k] * P[EST_ATT + k][c];
            }
            T[EST_VX + i][c] = v;
            T[EST_ATT + i][c] = a;
        }
    }
    for (int r = 0; r < EST_STATE_DIM; r++) {
        for (int i = 0; i < 3; i++) {
            P[r][EST_X + i] = T[r][EST_X + i] + dt * T[r][EST_VX + i];
            float v = T[r][EST_VX + i], a = 0;
            for (int k = 0; k < 3; k++) {
                v += A[i][k] * T[r][EST_ATT + k];
                a += W[i][k] * T[r][EST_ATT + k];
            }
            P[r][EST_VX + i] = v;
            P[r][EST_ATT + i] = a;
        }
    }
}

void ekf_predict(estimator_t *est, const float acc[3], const float gyro[3], float dt)
{
    propagate_covariance(est, acc, gyro, dt);
    ekf_grow_uncertainty(est, dt);

    /* Nominal state: attitude at mid-window for the acceleration, then rotate fully. */
    float half[3] = {0.5f * gyro[0] * dt, 0.5f * gyro[1] * dt, 0.5f * gyro[2] * dt};
    float q_mid[4];
    memcpy(q_mid, est->quat, sizeof q_mid);
    quat_rotate_body(q_mid, half);
    float r_mid[3][3];
    quat_to_rot(q_mid, r_mid);
    float a_world[3];
    for (int i = 0; i < 3; i++)
        a_world[i] = r_mid[i][0] * acc[0] + r_mid[i][1] * acc[1] + r_mid[i][2] * acc[2];
    a_world[2] -= EST_GRAVITY;
    for (int i = 0; i < 3; i++) {
        est->pos[i] += est->vel[i] * dt + 0.5f * a_world[i] * dt * dt;
        est->vel[i] += a_world[i] * dt;
    }
    const float full[3] = {gyro[0] * dt, gyro[1] * dt, gyro[2] * dt};
    quat_rotate_body(est->quat, full);
    quat_to_rot(est->quat, est->rot);
    ekf_condition_covariance(est);
}

void ekf_apply_error(estimator_t *est, const float dx[EST_STATE_DIM])
{
    for (int i = 0; i < 3; i++) {
        est->pos[i] += dx[EST_X + i];
        est->vel[i] += dx[EST_VX + i];
    }
    quat_rotate_body(est->quat, &dx[EST_ATT]);
    quat_to_rot(est->quat, est->rot);
    /* The covariance stays expressed about the new nominal attitude: for the small
     * corrections of one TDOA update the reset Jacobian I - [d/2]x is within float noise. */
}

/* Keep P symmetric and its variances within [EST_MIN_COV, EST_MAX_COV]. */
void ekf_condition_covariance(estimator_t *est)
{
    for (int i = 0; i < EST_STATE_DIM; i++) {
        for (int j = i + 1; j < EST_STATE_DIM; j++) {
            float m = 0.5f * (est->P[i][j] + est->P[j][i]);
            est->P[i][j] = m;
            est->P[j][i] = m;
        }
        if (est->P[i][i] > EST_MAX_COV) est->P[i][i] = EST_MAX_COV;
        if (!(est->P[i][i] >= EST_MIN_COV)) est->P[i][i] = EST_MIN_COV;  /* also catches NaN */
    }
}

int ekf_is_diverged(const estimator_t *est)
{
    float speed2 = 0;
    for (int i = 0; i < 3; i++) {
        if (!isfinite(est->pos[i]) || !isfinite(est->vel[i])) return 1;
        if (fabsf(est->pos[i]) > EST_MAX_POSITION) return 1;
        speed2 += est->vel[i] * est->vel[i];
    }
    if (speed2 > EST_MAX_SPEED * EST_MAX_SPEED) return 1;
    for (int i = 0; i < 4; i++)
        if (!isfinite(est->quat[i])) return 1;
    for (int i = 0; i < EST_STATE_DIM; i++)
        for (int j = 0; j < EST_STATE_DIM; j++)
            if (!isfinite(est->P[i][j])) return 1;
    return 0;
}

/* G P G^T + std^2 for a Jacobian G nonzero on position only. */
float ekf_innovation_variance(const estimator_t *est, const float h[3], float std)
{
    float s = std * std;
    for (int i = 0; i < 3; i++)
        s += h[i] * (est->P[i][0] * h[0] + est->P[i][1] * h[1] + est->P[i][2] * h[2]);
    return s;
}

/* The EKF update with one scalar measurement whose Jacobian h is nonzero on position
 * only (every measurement model of this estimator): K = P h^T / s, dx = K innovation,
 * P <- P - K (h P). Every measurement model calls down into it, as Crazyflie's
 * kalmanCoreScalarUpdate. */
void ekf_scalar_update(estimator_t *est, const float h[3], float innovation, float std)
{
    float PG[EST_STATE_DIM];
    for (int i = 0; i < EST_STATE_DIM; i++)
        PG[i] = est->P[i][0] * h[0] + est->P[i][1] * h[1] + est->P[i][2] * h[2];
    const float s = h[0] * PG[0] + h[1] * PG[1] + h[2] * PG[2] + std * std;
    const float inv_s = 1.0f / s;
    float dx[EST_STATE_DIM];
    for (int i = 0; i < EST_STATE_DIM; i++) dx[i] = PG[i] * inv_s * innovation;
    /* P <- P - K (G P) = P - PG PG^T / s  (rank one, stays symmetric) */
    for (int i = 0; i < EST_STATE_DIM; i++)
        for (int j = 0; j < EST_STATE_DIM; j++) est->P[i][j] -= PG[i] * PG[j] * inv_s;
    ekf_apply_error(est, dx);
}
