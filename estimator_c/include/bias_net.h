/*
 * The TDOA bias correction (paper Section III), in one of two forms:
 *
 *   pair  a network of the 14 features of the measurement: 14-30-30-30-1 ReLU, the
 *         predicted TDOA bias in metres (the paper's form);
 *   link  the range bias of one tag-anchor link, g(7 features of the link), one
 *         7-20-20-20-1 ReLU network shared by every link: TDOA bias = g(B) - g(A).
 *         A bias that lives on links, as the UWB bias does (the antennas' patterns,
 *         the airframe, each anchor's delay), is the difference of two link biases;
 *         a network of the pair can fit what is not, and does not transfer.
 *
 * Feature normalisation belongs to the model: inputs are standardised with the model's
 * own mean and scale, the output is scaled back. Weights are int8 with one float scale
 * per output neuron (row); biases stay float.
 */
#ifndef UWB_RIG_BIAS_NET_H
#define UWB_RIG_BIAS_NET_H

#include <stdint.h>

#define BN_INPUTS 14              /* features of one measurement (bn_features) */
#define BN_HIDDEN 30              /* pair form: three hidden layers of 30 */
#define BN_LANES 32               /* storage width of a pair layer: 30 neurons padded with two zero
                                   * neurons, so the loops have a trip count a multiple of the
                                   * SIMD width and compilers vectorise them at -O2 */
#define BN_LINK_INPUTS 7          /* features of one tag-anchor link */
#define BN_LINK_HIDDEN 20         /* link form: three hidden layers of 20, stored BN_LANES wide */
#define BN_LAYERS 4               /* three hidden layers and the output layer */
#define BN_ANCHORS 16             /* anchor ids with a range offset of their own (EST_MAX_ANCHORS) */

enum { BN_FORM_PAIR = 0, BN_FORM_LINK = 1 };

/* Which of the 14 measurement features are link A's and link B's, in link order:
 * anchor - tag (world, 3), the tag's azimuth in the anchor's frame, the anchor's azimuth
 * in the tag's heading-free frame, the same two elevations (bias_features.c). */
#define BN_LINK_A {0, 1, 2, 6, 8, 10, 12}
#define BN_LINK_B {3, 4, 5, 7, 9, 11, 13}

typedef struct {
    float in_mean[BN_INPUTS];
    float in_scale[BN_INPUTS];    /* x_norm = (x - mean) * scale */
    float out_scale;              /* bias = out_scale * y + out_offset */
    float out_offset;
    /* Weights stored input-major (w[j][i]: input j to output i), so a layer is a sum of
     * scaled columns that vectorises without reordering float additions. */
    int8_t w1[BN_INPUTS][BN_LANES];
    int8_t w2[BN_HIDDEN][BN_LANES];
    int8_t w3[BN_HIDDEN][BN_LANES];
    int8_t w4[BN_HIDDEN];
    float s1[BN_LANES], s2[BN_LANES], s3[BN_LANES], s4; /* per-output weight scales */
    float b1[BN_LANES], b2[BN_LANES], b3[BN_LANES], b4; /* padding neurons: all zero */
} bn_pair_t;

typedef struct {
    float in_mean[BN_LINK_INPUTS];
    float in_scale[BN_LINK_INPUTS];
    float out_scale;              /* link bias = out_scale * y (offsets cancel in a difference) */
    int8_t w1[BN_LINK_INPUTS][BN_LANES];   /* padded as the pair form's layers: zero neurons */
    int8_t w2[BN_LINK_HIDDEN][BN_LANES];
    int8_t w3[BN_LINK_HIDDEN][BN_LANES];
    int8_t w4[BN_LINK_HIDDEN];
    float s1[BN_LANES], s2[BN_LANES], s3[BN_LANES], s4;
    float b1[BN_LANES], b2[BN_LANES], b3[BN_LANES], b4;
    /* Each anchor's own range offset (its antenna delay's error, m), added to the link's
     * bias: zero for an anchor the model never saw, and for every anchor of a model
     * whose network tells anchors apart by their position. */
    float anchor_offset[BN_ANCHORS];
} bn_link_t;

/* bias_net_t.anchors of a model that corrects every anchor (one saved before models
 * carried the anchors they were trained on). */
#define BN_EVERY_ANCHOR 0xFFFFFFFFu

typedef struct {
    uint32_t form;                /* BN_FORM_PAIR or BN_FORM_LINK */
    /* Bit k set: the model was trained on measurements of anchor id k. A measurement
     * with an anchor it never saw is not corrected: a network that tells anchors apart
     * by their position only extrapolates to a new one, and widened the error there. */
    uint32_t anchors;
    union {
        bn_pair_t pair;
        bn_link_t link;
    } u;
} bias_net_t;

/* The 14 features of one TDOA measurement (see bias_features.c for the order). */
void bn_features(const float tag_pos[3], const float tag_rot[3][3],
                 const float anchor_a_pos[3], const float anchor_a_rot[3][3],
                 const float anchor_b_pos[3], const float anchor_b_rot[3][3],
                 float features[BN_INPUTS]);

/* Predicted TDOA bias (m) of the measurement between anchors id_a and id_b, for raw
 * (unnormalised) features, in either form; 0 when the model never saw one of them. */
float bn_predict(const bias_net_t *net, const float features[BN_INPUTS], unsigned id_a, unsigned id_b);

/* The link form's range bias (m) of one link, from its raw link features. */
float bn_link_bias(const bn_link_t *net, const float link[BN_LINK_INPUTS]);

#endif
