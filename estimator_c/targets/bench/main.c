/* Host benchmark driver: replays one session file through the estimator, so a
 * profiler (valgrind --tool=callgrind) can count the instructions of each call.
 *
 * Session file (little-endian, written by benchmarks/cost.py):
 *   "UWBS" | est_params_t | u32 n_anchors | n x {u8 id, f32 pos[3], f32 quat[4]}
 *   | u8 has_net | bias_net_t if has_net | u32 t0_us, f32 pos[3], f32 quat[4]
 *   | u32 n_events | n x est_event_t
 * Prints the final counters so the work cannot be optimised away. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "estimator.h"

static int read_exact(FILE *f, void *dst, size_t n)
{
    return fread(dst, 1, n, f) == n ? 0 : -1;
}

static int load_anchors(FILE *f, estimator_t *est)
{
    uint32_t n;
    if (read_exact(f, &n, sizeof n)) return -1;
    for (uint32_t k = 0; k < n; k++) {
        uint8_t id;
        float pos[3], quat[4];
        if (read_exact(f, &id, 1) || read_exact(f, pos, sizeof pos) || read_exact(f, quat, sizeof quat)) return -1;
        if (est_set_anchor(est, id, pos, quat)) fprintf(stderr, "anchor %u rejected\n", id);
    }
    return 0;
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: %s SESSION_FILE\n", argv[0]);
        return 2;
    }
    FILE *f = fopen(argv[1], "rb");
    if (!f) {
        perror(argv[1]);
        return 2;
    }
    static estimator_t est;
    static bias_net_t net;
    est_params_t params;
    char magic[4];
    uint8_t has_net = 0;
    uint32_t t0_us, n_events;
    float pos[3], quat[4];
    int bad = read_exact(f, magic, 4) || memcmp(magic, "UWBS", 4) || read_exact(f, &params, sizeof params);
    if (!bad) {
        est_init(&est, &params);
        bad = load_anchors(f, &est) || read_exact(f, &has_net, 1) || (has_net && read_exact(f, &net, sizeof net))
              || read_exact(f, &t0_us, 4) || read_exact(f, pos, sizeof pos) || read_exact(f, quat, sizeof quat)
              || read_exact(f, &n_events, 4);
    }
    est_event_t *events = bad ? NULL : malloc((size_t)n_events * sizeof *events);
    if (bad || !events || read_exact(f, events, (size_t)n_events * sizeof *events)) {
        fprintf(stderr, "%s: not a complete session file\n", argv[1]);
        return 2;
    }
    fclose(f);
    if (has_net) est_set_bias_net(&est, &net);
    est_reset(&est, t0_us, pos, quat);
    est_output_t out;
    for (uint32_t k = 0; k < n_events; k++) est_handle_event(&est, &events[k], &out);
    est_get_output(&est, &out);
    printf("steps %u accepted %u downweighted %u rejected %u resets %u\n", (unsigned)out.counters.steps,
           (unsigned)out.counters.tdoa_accepted, (unsigned)out.counters.tdoa_downweighted,
           (unsigned)out.counters.tdoa_rejected, (unsigned)out.counters.resets);
    free(events);
    return 0;
}
