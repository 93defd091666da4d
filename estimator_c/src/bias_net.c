/* Bias-correction inference: standardise, three int8 dense ReLU layers, one linear
 * output, scale back; the link form evaluates its network on both links of the
 * measurement and takes the difference. Each layer accumulates scaled weight columns
 * (y += w[j][:] * x[j]), a loop over independent outputs that compilers vectorise
 * (restrict pointers and a width of BN_LANES, a multiple of the int8 SIMD width, make
 * that happen at -O2; both forms store their layers that wide, padded with zero
 * neurons). */
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

static float linear_out(int n, const int8_t *w, float scale, float bias, const float *x)
{
    float out = 0.0f;
    for (int i = 0; i < n; i++) out += (float)w[i] * x[i];
    return out * scale + bias;
}

static float pair_predict(const bn_pair_t *net, const float features[BN_INPUTS])
{
    float x[BN_INPUTS];
    for (int i = 0; i < BN_INPUTS; i++) x[i] = (features[i] - net->in_mean[i]) * net->in_scale[i];
    float h1[BN_LANES], h2[BN_LANES], h3[BN_LANES];
    dense_relu(BN_INPUTS, &net->w1[0][0], net->s1, net->b1, x, h1);
    dense_relu(BN_HIDDEN, &net->w2[0][0], net->s2, net->b2, h1, h2);
    dense_relu(BN_HIDDEN, &net->w3[0][0], net->s3, net->b3, h2, h3);
    return linear_out(BN_HIDDEN, net->w4, net->s4, net->b4, h3) * net->out_scale + net->out_offset;
}

float bn_link_bias(const bn_link_t *net, const float link[BN_LINK_INPUTS])
{
    float x[BN_LINK_INPUTS];
    for (int i = 0; i < BN_LINK_INPUTS; i++) x[i] = (link[i] - net->in_mean[i]) * net->in_scale[i];
    float h1[BN_LANES], h2[BN_LANES], h3[BN_LANES];
    dense_relu(BN_LINK_INPUTS, &net->w1[0][0], net->s1, net->b1, x, h1);
    dense_relu(BN_LINK_HIDDEN, &net->w2[0][0], net->s2, net->b2, h1, h2);
    dense_relu(BN_LINK_HIDDEN, &net->w3[0][0], net->s3, net->b3, h2, h3);
    return linear_out(BN_LINK_HIDDEN, net->w4, net->s4, net->b4, h3) * net->out_scale;
}

static float anchor_offset(const bn_link_t *net, unsigned id)
{
    return id < BN_ANCHORS ? net->anchor_offset[id] : 0.0f;
}

static float link_predict(const bn_link_t *net, const float features[BN_INPUTS], unsigned id_a, unsigned id_b)
{
    static const int index_a[BN_LINK_INPUTS] = BN_LINK_A, index_b[BN_LINK_INPUTS] = BN_LINK_B;
    float a[BN_LINK_INPUTS], b[BN_LINK_INPUTS];
    for (int i = 0; i < BN_LINK_INPUTS; i++) {
        a[i] = features[index_a[i]];
        b[i] = features[index_b[i]];
    }
    return bn_link_bias(net, b) + anchor_offset(net, id_b) - bn_link_bias(net, a) - anchor_offset(net, id_a);
}

static int trained_on(const bias_net_t *net, unsigned id)
{
    return net->anchors == BN_EVERY_ANCHOR || (id < 32u && ((net->anchors >> id) & 1u));
}

float bn_predict(const bias_net_t *net, const float features[BN_INPUTS], unsigned id_a, unsigned id_b)
{
    if (!trained_on(net, id_a) || !trained_on(net, id_b)) return 0.0f;
    return net->form == BN_FORM_LINK ? link_predict(&net->u.link, features, id_a, id_b)
                                     : pair_predict(&net->u.pair, features);
}
