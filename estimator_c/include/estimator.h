/*
 * uwb-rig onboard estimator: IMU-driven error-state EKF with TDOA updates,
 * learned TDOA bias correction and an M-estimation (Geman-McClure, IRLS)
 * robust update. C99, float32, no heap, no hidden state: everything lives in
 * one estimator_t passed by pointer.
 *
 * Use: est_init, est_set_anchor for every anchor, optionally est_set_bias_net,
 * est_reset with the start pose; then feed est_handle_event with accelerometer,
 * gyroscope and TDOA events in time order and a STEP event every 10 ms (100 Hz).
 * A STEP predicts with the averaged IMU samples of the window, then applies the
 * TDOA measurements queued during it, and fills an est_output_t.
 */
#ifndef UWB_RIG_ESTIMATOR_H
#define UWB_RIG_ESTIMATOR_H

#include <stdint.h>

#include "bias_net.h"

#define EST_STATE_DIM 9            /* error state: position, velocity, attitude */
#define EST_MAX_ANCHORS 16         /* anchor ids 0..EST_MAX_ANCHORS-1 */
_Static_assert(EST_MAX_ANCHORS == BN_ANCHORS, "the bias model has one offset per anchor id");
#define EST_TDOA_QUEUE 32          /* TDOA measurements buffered within one window */
#define EST_API_VERSION 4          /* 2: est_params_t grew trust_prior_n (PARAM 12); 3: est_reset clears the counters;
                                      4: est_params_t grew anchor_bias_c (PARAM 13) */
#define EST_TRUST_PRIOR_N 2000.0f  /* correction trust's prior, in pseudo-measurements (session 69) */
#define EST_ANCHOR_BIAS_C 0.15f    /* m, chosen by transfer (session 83) */
#define EST_ANCHOR_BIAS_WINDOW_S 1.0f  /* s over which an anchor's tracked range bias forgets */
#define EST_ANCHOR_BIAS_PRIOR_N 10.0f  /* measurements of zero bias each anchor's estimate starts from */
#define EST_ANCHOR_BIAS_MIN_PARTNERS 4 /* anchors paired with one before its bias weights it (TDOA3, not the TDOA2 ring) */
_Static_assert(EST_MAX_ANCHORS <= 16, "partner sets are 16-bit masks");

/* Error-state indices. */
#define EST_X 0
#define EST_VX 3
#define EST_ATT 6

typedef enum {
    EST_EV_ACCEL = 1, /* v = specific force, body frame, m/s^2 */
    EST_EV_GYRO = 2,  /* v = angular rate, body frame, rad/s */
    EST_EV_TDOA = 3,  /* id_a, id_b, v[0] = |p - a_B| - |p - a_A| in m */
    EST_EV_STEP = 4   /* end of a window: predict to t_us, apply queued TDOA */
} est_event_kind_t;

/* One input event (20 bytes). The same record is used by the batch replay of the
 * native library and, packed, by the wire protocol. */
typedef struct {
    uint32_t t_us;
    uint8_t kind;
    uint8_t id_a;
    uint8_t id_b;
    uint8_t reserved;
    float v[3];
} est_event_t;

typedef enum {
    EST_OK = 0,
    EST_OUTPUT = 1,            /* a STEP produced an estimate */
    EST_REJECTED = -1          /* the input was counted as rejected and ignored */
} est_status_t;

/* Why inputs were rejected; indices into est_counters_t.rejected. */
typedef enum {
    EST_REJ_NONFINITE = 0,     /* NaN or inf in the value, or in its bias correction */
    EST_REJ_UNKNOWN_ANCHOR,    /* id not configured */
    EST_REJ_SAME_ANCHOR,       /* id_a == id_b */
    EST_REJ_EXCEEDS_BASELINE,  /* |distance_diff| larger than the anchors' separation */
    EST_REJ_TIME_BACKWARDS,    /* timestamp before the last STEP */
    EST_REJ_QUEUE_FULL,        /* more TDOA in one window than EST_TDOA_QUEUE */
    EST_REJ_BAD_KIND,          /* unknown event kind */
    EST_REJ_GATE,              /* innovation beyond the hard gate */
    EST_REJ_COUNT
} est_reject_reason_t;

/* A flight's counts: cleared by est_reset (a new flight), kept through a divergence reset. */
typedef struct {
    uint32_t steps;
    uint32_t imu_samples;
    uint32_t imu_gaps;         /* STEPs without any IMU sample in their window */
    uint32_t tdoa_accepted;    /* final robust weight >= EST_WEIGHT_ACCEPTED (or plain update) */
    uint32_t tdoa_downweighted;
    uint32_t tdoa_rejected;    /* weight < EST_WEIGHT_REJECTED, or any reject reason below */
    uint32_t rejected[EST_REJ_COUNT];
    uint32_t resets;           /* divergence resets */
    uint32_t tdoa_anchor_weighted; /* blocked-anchor weight < EST_WEIGHT_ACCEPTED (anchor_bias.c) */
} est_counters_t;

typedef struct {
    float tdoa_std;            /* m, measurement noise */
    float accel_noise;         /* m/s^2, per-sample-average process noise on velocity */
    float gyro_noise;          /* rad/s, process noise on attitude */
    float position_noise;      /* m/sqrt(s), random walk on position */
    float velocity_noise;      /* m/s/sqrt(s), random walk on velocity */
    float gate_m;              /* hard innovation gate (m) */
    float gm_state_c2;         /* Geman-McClure scale (c^2) on the whitened prior error */
    float gm_meas_c2;          /* Geman-McClure scale (c^2) on the whitened measurement error */
    uint8_t robust;            /* 1: M-estimation update; 0: plain EKF update */
    uint8_t irls_iterations;   /* fixed IRLS iterations (2 on the board) */
    uint8_t use_bias_net;      /* subtract the network's bias prediction */
    uint8_t thrust_only;       /* use only the z specific force (x/y read drag + vibration in flight) */
    float trust_prior_n;       /* correction trust: pseudo-measurements at full trust; < 0: always full */
    float anchor_bias_c;       /* m: scale of the tracked anchor bias that down-weights its measurements; 0: off */
} est_params_t;

/* How far this flight's measurements follow the bias correction: the robust regression
 * of the uncorrected innovation on the correction, accumulated over the flight (cleared
 * by est_reset, kept through a divergence reset; float sums hold flights of hours). */
typedef struct {
    float s_cc;                /* sum of weight * c^2 */
    float s_cv;                /* sum of weight * c * innovation without correction */
    float n;                   /* sum of weights */
} est_trust_t;

/* Each anchor's range bias tracked from the innovations (anchor_bias.c): cleared when
 * the filter (re)starts. */
typedef struct {
    float bias[EST_MAX_ANCHORS];   /* m, summing to zero over the anchors heard */
    float n[EST_MAX_ANCHORS];      /* weighted measurements behind it, forgetting; 0: not heard */
    float excess[EST_MAX_ANCHORS]; /* m: what of bias no position error explains */
    uint16_t partners[EST_MAX_ANCHORS];        /* anchors paired with it in this window (a bit each) */
    uint16_t partners_before[EST_MAX_ANCHORS]; /* and in the window before */
    float window_s;                /* s into this partner window */
} est_anchor_bias_t;

typedef struct {
    float pos[3];
    float quat[4];             /* x, y, z, w: anchor -> world */
    float rot[3][3];           /* same rotation as a matrix */
    uint8_t valid;
} est_anchor_t;

typedef struct {
    uint32_t t_us;
    float pos[3];
    float vel[3];
    float quat[4];             /* x, y, z, w: body -> world */
    float cov_diag[EST_STATE_DIM];
    est_counters_t counters;
} est_output_t;

typedef struct {
    uint32_t t_us;             /* measurement time */
    float value;               /* measured distance difference (m) */
    uint8_t id_a, id_b;
} est_tdoa_t;

/* Optional cost measurement of the last STEP's calls, in the ticks of a board clock
 * (cycles, instructions or nanoseconds); filled only when est_set_clock gave a clock. */
typedef uint32_t (*est_clock_t)(void);
typedef struct {
    uint32_t predict;          /* the prediction */
    uint32_t tdoa_total;       /* all TDOA updates of the window */
    uint32_t tdoa_max;         /* the most expensive single TDOA update */
    uint8_t n_tdoa;
} est_step_cost_t;

typedef struct {
    est_params_t params;
    /* nominal state */
    float pos[3];
    float vel[3];
    float quat[4];             /* x, y, z, w */
    float rot[3][3];           /* body -> world, kept in sync with quat */
    float P[EST_STATE_DIM][EST_STATE_DIM];
    /* IMU accumulation over the current window */
    float acc_sum[3];
    float gyro_sum[3];
    uint16_t acc_n;
    uint16_t gyro_n;
    float acc_last[3];         /* last window's averages, held over IMU gaps */
    float gyro_last[3];
    uint32_t t_step_us;        /* time of the last STEP (prediction) */
    uint8_t started;
    /* TDOA queue of the current window */
    est_tdoa_t queue[EST_TDOA_QUEUE];
    uint8_t queue_n;
    est_anchor_t anchors[EST_MAX_ANCHORS];
    const bias_net_t *net;
    est_trust_t trust;
    est_anchor_bias_t anchor_bias;
    est_counters_t counters;
    est_clock_t clock;
    est_step_cost_t cost;
} estimator_t;

void est_default_params(est_params_t *params);
void est_init(estimator_t *est, const est_params_t *params);
/* The share of the bias correction applied now, in [0, 1] (est_trust_t). */
float est_correction_trust(const estimator_t *est);
int est_set_anchor(estimator_t *est, uint8_t id, const float pos[3], const float quat[4]);
/* Forget every anchor (a board configured for another flight: its anchors are set anew). */
void est_clear_anchors(estimator_t *est);
void est_set_bias_net(estimator_t *est, const bias_net_t *net);
void est_set_clock(estimator_t *est, est_clock_t clock);
/* Start (or restart) at a pose: quat may be NULL for level, yaw 0. */
void est_reset(estimator_t *est, uint32_t t_us, const float pos[3], const float quat[4]);
est_status_t est_handle_event(estimator_t *est, const est_event_t *ev, est_output_t *out);
void est_get_output(const estimator_t *est, est_output_t *out);

#endif
