/* Host-only helpers for the Python binding (ctypes): struct sizes, so the binding
 * can check its mirrors of the C structs, and the size of estimator_t, so Python
 * can own the memory (the estimator itself never allocates). */
#include <stddef.h>

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
