#ifndef UWB_RIG_REPLAY_H
#define UWB_RIG_REPLAY_H

#include <stddef.h>

#include "estimator.h"

/* Feed n_events events in order; write one output per STEP (up to max_outputs).
 * Returns the number of outputs written. */
size_t est_replay(estimator_t *est, const est_event_t *events, size_t n_events,
                  est_output_t *outputs, size_t max_outputs);

#endif
