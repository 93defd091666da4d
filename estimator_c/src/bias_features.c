/* The 14 bias-network features of one TDOA measurement (paper Section III, Fig. 3),
 * in the paper's order chi = [dp_A, dp_B, alpha, beta]:
 *
 *   0-2   a_A - p                       relative position of anchor A (world, m)
 *   3-5   a_B - p                       relative position of anchor B (world, m)
 *   6, 7  azimuth of the tag in anchor A's frame, in anchor B's frame
 *   8, 9  azimuth of anchor A in the tag's (heading-free) body frame, of anchor B
 *   10,11 elevation of the tag in anchor A's frame, in anchor B's frame
 *   12,13 elevation of anchor A in the tag's (heading-free) body frame, of anchor B
 *
 * The tag's frame keeps its tilt but not its heading: the estimator cannot observe yaw
 * (it uses only the thrust axis of the accelerometer and has no magnetometer; on the
 * shared flights its yaw drifts 20-30 degrees while the drone holds its heading), so a
 * feature depending on the estimated yaw would differ between training and flight.
 * The heading-free frame is the smallest rotation taking world z onto the body z axis.
 *
 * azimuth = atan2(y, x), elevation = atan2(z, sqrt(x^2 + y^2)) of the direction
 * expressed in the named frame (radians). The Python dataset builder calls this
 * very function through the native library, so training and flight agree. */
#include <math.h>

#include "bias_net.h"

/* atan2 to within 1e-5 rad (Abramowitz & Stegun 4.4.49 on [-1, 1], folded by octant),
 * instead of libm's atan2f, whose code and tables would cost the firmware kilobytes.
 * Training computes its features with this very function, so the network never sees
 * a different angle from the one it gets in flight. */
static float fast_atan2f(float y, float x)
{
    const float ax = fabsf(x), ay = fabsf(y);
    if (ax == 0.0f && ay == 0.0f) return 0.0f;
    const int swap = ay > ax;
    const float z = swap ? ax / ay : ay / ax, z2 = z * z;
    float a = z * (0.9998660f + z2 * (-0.3302995f + z2 * (0.1801410f + z2 * (-0.0851330f + z2 * 0.0208351f))));
    if (swap) a = 1.57079632679f - a;
    if (x < 0.0f) a = 3.14159265359f - a;
    return y < 0.0f ? -a : a;
}

/* Direction v (world) expressed in the frame whose rotation (frame -> world) is r: r^T v. */
static void azimuth_elevation(const float r[3][3], const float v[3], float *azimuth, float *elevation)
{
    const float x = r[0][0] * v[0] + r[1][0] * v[1] + r[2][0] * v[2];
    const float y = r[0][1] * v[0] + r[1][1] * v[1] + r[2][1] * v[2];
    const float z = r[0][2] * v[0] + r[1][2] * v[1] + r[2][2] * v[2];
    *azimuth = fast_atan2f(y, x);
    *elevation = fast_atan2f(z, sqrtf(x * x + y * y));
}

/* Tilt of r without its heading: the rotation about the axis e3 x b3 by the angle between
 * e3 and b3 (b3 = body z in world, the third column of r):
 * T = I + [k]x + [k]x^2 / (1 + c), k = e3 x b3, c = e3 . b3 (Rodrigues). */
static void heading_free(const float r[3][3], float t[3][3])
{
    const float k[3] = {-r[1][2], r[0][2], 0.0f};
    float c = r[2][2];
    if (c < -0.999f) c = -0.999f; /* upside down: any heading is as good; keep it finite */
    const float kx[3][3] = {{0, -k[2], k[1]}, {k[2], 0, -k[0]}, {-k[1], k[0], 0}};
    const float inv = 1.0f / (1.0f + c);
    for (int i = 0; i < 3; i++) {
        for (int j = 0; j < 3; j++) {
            float sq = 0.0f;
            for (int m = 0; m < 3; m++) sq += kx[i][m] * kx[m][j];
            t[i][j] = (i == j ? 1.0f : 0.0f) + kx[i][j] + sq * inv;
        }
    }
}

void bn_features(const float tag_pos[3], const float tag_rot[3][3],
                 const float anchor_a_pos[3], const float anchor_a_rot[3][3],
                 const float anchor_b_pos[3], const float anchor_b_rot[3][3],
                 float f[BN_INPUTS])
{
    float to_a[3], to_b[3], from_a[3], from_b[3];
    for (int i = 0; i < 3; i++) {
        to_a[i] = anchor_a_pos[i] - tag_pos[i];
        to_b[i] = anchor_b_pos[i] - tag_pos[i];
        from_a[i] = -to_a[i];
        from_b[i] = -to_b[i];
        f[i] = to_a[i];
        f[3 + i] = to_b[i];
    }
    azimuth_elevation(anchor_a_rot, from_a, &f[6], &f[10]);
    azimuth_elevation(anchor_b_rot, from_b, &f[7], &f[11]);
    float tilt[3][3];
    heading_free(tag_rot, tilt);
    azimuth_elevation(tilt, to_a, &f[8], &f[12]);
    azimuth_elevation(tilt, to_b, &f[9], &f[13]);
}
