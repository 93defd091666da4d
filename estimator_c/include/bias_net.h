/*
 * The TDOA bias network (paper Section III): 14 features -> 3 dense ReLU layers
 * of 30 -> one linear output, the predicted bias in metres. Feature
 * normalisation belongs to the model: inputs are standardised with the model's
 * own mean and scale, the output is scaled back.
 *
 * Weights are int8 with one float scale per output neuron (row), which keeps
 * the whole model near 2.5 kB of flash; biases stay float.
 */
#ifndef UWB_RIG_BIAS_NET_H
#define UWB_RIG_BIAS_NET_H

#include <stdint.h>

#define BN_INPUTS 14
#define BN_HIDDEN 30
#define BN_LAYERS 4               /* three hidden layers and the output layer */
#define BN_LANES 32               /* storage width of a layer: 30 neurons padded with two zero
                                   * neurons, so the loops have a trip count a multiple of the
                                   * SIMD width and compilers vectorise them at -O2 */

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
} bias_net_t;

/* The 14 features of one TDOA measurement (see bias_features.c for the order). */
void bn_features(const float tag_pos[3], const float tag_rot[3][3],
                 const float anchor_a_pos[3], const float anchor_a_rot[3][3],
                 const float anchor_b_pos[3], const float anchor_b_rot[3][3],
                 float features[BN_INPUTS]);

/* Predicted bias (m) for raw (unnormalised) features. */
float bn_predict(const bias_net_t *net, const float features[BN_INPUTS]);

#endif
