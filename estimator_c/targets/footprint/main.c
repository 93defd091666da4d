/* A minimal Cortex-M4F image that links the whole estimator (every entry point the
 * firmware uses), so `arm-none-eabi-size` counts the library code it pulls in too.
 * Built twice, with and without ESTIMATOR, the difference is the estimator's cost. */
#include "estimator.h"

#ifdef ESTIMATOR
estimator_t g_estimator;
extern const bias_net_t g_bias_net;
#endif

int main(void)
{
#ifdef ESTIMATOR
    est_init(&g_estimator, 0);
    est_set_bias_net(&g_estimator, &g_bias_net);
    volatile est_event_t ev = {0};
    est_output_t out;
    est_handle_event(&g_estimator, (const est_event_t *)&ev, &out);
    return (int)out.pos[0];
#else
    return 0;
#endif
}

#ifdef ESTIMATOR
/* Weights live in flash (const): the footprint counts a full-size model. */
const bias_net_t g_bias_net = {.form = BN_FORM_LINK, .anchors = BN_EVERY_ANCHOR, .u.link = {.out_scale = 1.0f}};
#endif
