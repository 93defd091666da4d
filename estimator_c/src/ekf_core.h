/* Internal interface between the estimator's parts (not part of the public API). */
#ifndef UWB_RIG_EKF_CORE_H
#define UWB_RIG_EKF_CORE_H

#include "estimator.h"

#define EST_GRAVITY 9.81f
#define EST_MAX_POSITION 50.0f      /* m from the origin: beyond it the filter has diverged */
#define EST_MAX_SPEED 20.0f         /* m/s */
#define EST_MAX_COV 100.0f          /* largest variance kept in P */
#define EST_MIN_COV 1e-8f           /* smallest variance kept in P */
#define EST_MAX_DT 0.1f             /* s: longer windows only grow the covariance */
#define EST_NOMINAL_DT 0.01f
#define EST_INIT_POS_STD 0.1f
#define EST_INIT_VEL_STD 0.1f
#define EST_INIT_ATT_STD 0.05f
#define EST_WEIGHT_ACCEPTED 0.5f    /* robust weight at or above which a TDOA counts as accepted */
#define EST_WEIGHT_REJECTED 0.05f   /* below it, as rejected */
#define EST_GATE_SIGMAS 5.0f        /* hard gate: innovation beyond gate_m and this many sigmas */

/* ekf_core.c */
void ekf_predict(estimator_t *est, const float acc[3], const float gyro[3], float dt);
void ekf_transition_blocks(const estimator_t *est, const float acc[3], const float gyro[3], float dt,
                           float A[3][3], float W[3][3]);
void ekf_grow_uncertainty(estimator_t *est, float dt);
void ekf_condition_covariance(estimator_t *est);
void ekf_apply_error(estimator_t *est, const float dx[EST_STATE_DIM]);
int ekf_is_diverged(const estimator_t *est);
void quat_to_rot(const float q[4], float r[3][3]);
/* the one scalar measurement update (Jacobian nonzero on position only, measurement
 * noise std) and its innovation variance */
float ekf_innovation_variance(const estimator_t *est, const float h[3], float std);
void ekf_scalar_update(estimator_t *est, const float h[3], float innovation, float std);

/* mm_tdoa.c */
float tdoa_predict(const float pos[3], const float a[3], const float b[3], float grad[3]);
void tdoa_update(estimator_t *est, const est_tdoa_t *m);
float tdoa_trust_weight(const estimator_t *est);

/* anchor_bias.c */
void anchor_bias_step(estimator_t *est, float dt);
float anchor_bias_anchor_weight(const estimator_t *est, uint8_t k);
float anchor_bias_weight(const estimator_t *est, uint8_t a, uint8_t b);
void anchor_bias_observe(estimator_t *est, uint8_t a, uint8_t b, float innovation);

/* mm_tdoa_robust.c: the M-estimation counterpart of ekf_scalar_update */
float ekf_robust_scalar_update(estimator_t *est, const float h[3], float innovation, float std);

/* robust_weight.c */
float gm_weight(float e, float c2);
int cholesky_lower(const float A[EST_STATE_DIM][EST_STATE_DIM], float L[EST_STATE_DIM][EST_STATE_DIM]);

#endif
