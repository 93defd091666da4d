/* Bias-network inference: standardise, three int8 dense ReLU layers of 30, one
 * linear output, scale back. Each layer accumulates scaled weight columns
 * (y += w[j][:] * x[j]), a loop over independent outputs that compilers vectorise
 * (restrict pointers and a padded width of BN_LANES make that happen at -O2). */
#include "bias_net.h"

static void dense_relu(int n_in, const int8_t *restrict w, const float *restrict scale,
                       const float *restrict bias, const float *restrict x, float *restrict y)
{
    float acc[BN_LANES] = {0};
    for (int j = 0; j < n_in; j++) {
        const int8_t *col = w + j * BN_LANES;
        const float xj = x[j];
        for (int i = 0; i < BN_LANES; i++) acc[i] += (float)col[i] * xj;
    }
    for (int i = 0; i < BN_LANES; i++) {
        const float v = acc[i] * scale[i] + bias[i];
        y[i] = v > 0.0f ? v : 0.0f;
    }
}

float bn_predict(const bias_net_t *net, const float features[BN_INPUTS])
{
    float x[BN_INPUTS];
    for (int i = 0; i < BN_INPUTS; i++) x[i] = (features[i] - net->in_mean[i]) * net->in_scale[i];
    float h1[BN_LANES], h2[BN_LANES], h3[BN_LANES];
    dense_relu(BN_INPUTS, &net->w1[0][0], net->s1, net->b1, x, h1);
    dense_relu(BN_HIDDEN, &net->w2[0][0], net->s2, net->b2, h1, h2);
    dense_relu(BN_HIDDEN, &net->w3[0][0], net->s3, net->b3, h2, h3);
    float out = 0.0f;
    for (int i = 0; i < BN_HIDDEN; i++) out += (float)net->w4[i] * h3[i];
    out = out * net->s4 + net->b4;
    return out * net->out_scale + net->out_offset;
}
