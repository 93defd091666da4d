/* Host-only helpers for the Python binding (ctypes): struct sizes, so the binding
 * can check its mirrors of the C structs, and the size of estimator_t, so Python
 * can own the memory (the estimator itself never allocates). */
#include <stddef.h>

#include "ekf_core.h"
#include "estimator.h"

size_t est_sizeof_estimator(void) { return sizeof(estimator_t); }
size_t est_sizeof_event(void) { return sizeof(est_event_t); }
size_t est_sizeof_output(void) { return sizeof(est_output_t); }
size_t est_sizeof_params(void) { return sizeof(est_params_t); }
size_t est_sizeof_bias_net(void) { return sizeof(bias_net_t); }

void est_copy_covariance(const estimator_t *est, float out[EST_STATE_DIM * EST_STATE_DIM])
{
    for (int i = 0; i < EST_STATE_DIM; i++)
        for (int j = 0; j < EST_STATE_DIM; j++) out[i * EST_STATE_DIM + j] = est->P[i][j];
}

/* Each anchor's weight in the blocked-anchor weighting now (1: not discounted), so the
 * rig can say which anchors the count tdoa_anchor_weighted is made of. */
void est_copy_anchor_weights(const estimator_t *est, float out[EST_MAX_ANCHORS])
{
    for (int k = 0; k < EST_MAX_ANCHORS; k++) out[k] = anchor_bias_anchor_weight(est, (uint8_t)k);
}

/* bn_features over n measurements (row-major arrays), so the training set is
 * computed by exactly the code the estimator runs, without a ctypes call per row. */
void bn_features_batch(size_t n, const float (*tag_pos)[3], const float (*tag_rot)[3][3],
                       const float (*a_pos)[3], const float (*a_rot)[3][3],
                       const float (*b_pos)[3], const float (*b_rot)[3][3], float (*out)[BN_INPUTS])
{
    for (size_t k = 0; k < n; k++)
        bn_features(tag_pos[k], tag_rot[k], a_pos[k], a_rot[k], b_pos[k], b_rot[k], out[k]);
}
