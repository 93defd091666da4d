/* Batch replay for hosts: run an array of time-ordered events through the
 * estimator and collect one output per STEP. Used by the native library (Python
 * binding) so a whole flight runs in C without a call per sample. */
#include "replay.h"

size_t est_replay(estimator_t *est, const est_event_t *events, size_t n_events,
                  est_output_t *outputs, size_t max_outputs)
{
    size_t n_out = 0;
    for (size_t k = 0; k < n_events; k++) {
        est_output_t *slot = n_out < max_outputs ? &outputs[n_out] : 0;
        if (est_handle_event(est, &events[k], slot) == EST_OUTPUT && slot) n_out++;
    }
    return n_out;
}
