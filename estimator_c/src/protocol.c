/* Framing, checksums and field encoding of the wire protocol (see protocol.h). */
#include "protocol.h"

#include <string.h>

uint16_t proto_crc16(const uint8_t *data, size_t n)
{
    uint16_t crc = 0xFFFF;
    for (size_t i = 0; i < n; i++) {
        crc ^= (uint16_t)(data[i] << 8);
        for (int b = 0; b < 8; b++) crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x1021) : (uint16_t)(crc << 1);
    }
    return crc;
}

size_t proto_cobs_encode(const uint8_t *in, size_t n, uint8_t *out)
{
    size_t code_at = 0, o = 1;
    uint8_t code = 1;
    for (size_t i = 0; i < n; i++) {
        if (in[i] == 0) {
            out[code_at] = code;
            code_at = o++;
            code = 1;
        } else {
            out[o++] = in[i];
            code++;
        }
    }
    out[code_at] = code;
    return o;
}

int proto_cobs_decode(const uint8_t *in, size_t n, uint8_t *out)
{
    size_t i = 0, o = 0;
    while (i < n) {
        const uint8_t code = in[i++];
        if (code == 0 || i + code - 1 > n) return -1;
        for (uint8_t k = 1; k < code; k++) {
            if (in[i] == 0) return -1;
            out[o++] = in[i++];
        }
        if (code < 0xFF && i < n) out[o++] = 0;
    }
    return (int)o;
}

size_t proto_frame(const uint8_t *payload, size_t n, uint8_t out[PROTO_MAX_ENCODED])
{
    if (n == 0 || n > PROTO_MAX_PAYLOAD) return 0;
    uint8_t raw[PROTO_MAX_PAYLOAD + 2];
    memcpy(raw, payload, n);
    proto_put_u16(&raw[n], proto_crc16(payload, n));
    size_t len = proto_cobs_encode(raw, n + 2, out);
    out[len++] = 0;
    return len;
}

void proto_parser_init(proto_parser_t *p)
{
    memset(p, 0, sizeof *p);
}

static int finish_frame(proto_parser_t *p, uint8_t payload[PROTO_MAX_PAYLOAD])
{
    uint8_t raw[PROTO_MAX_FRAME];
    const int n = proto_cobs_decode(p->buf, p->len, raw);
    p->len = 0;
    if (n < 3 || n > PROTO_MAX_PAYLOAD + 2 || proto_crc16(raw, (size_t)n - 2) != proto_get_u16(&raw[n - 2])) {
        p->frames_bad++;
        return 0;
    }
    memcpy(payload, raw, (size_t)n - 2);
    p->frames_ok++;
    return n - 2;
}

int proto_parser_feed(proto_parser_t *p, uint8_t byte, uint8_t payload[PROTO_MAX_PAYLOAD])
{
    if (byte == 0) {
        if (p->overflow) {
            p->overflow = 0;
            p->len = 0;
            p->frames_bad++;
            return 0;
        }
        if (p->len == 0) return 0;   /* idle delimiters are allowed (resynchronisation) */
        return finish_frame(p, payload);
    }
    if (p->overflow) {
        p->bytes_dropped++;
        return 0;
    }
    if (p->len >= sizeof p->buf) {
        p->overflow = 1;
        p->bytes_dropped += (uint32_t)p->len + 1;
        p->len = 0;
        return 0;
    }
    p->buf[p->len++] = byte;
    return 0;
}

void proto_put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
}

void proto_put_u32(uint8_t *p, uint32_t v)
{
    for (int i = 0; i < 4; i++) p[i] = (uint8_t)(v >> (8 * i));
}

void proto_put_f32(uint8_t *p, float v)
{
    uint32_t u;
    memcpy(&u, &v, 4);
    proto_put_u32(p, u);
}

uint16_t proto_get_u16(const uint8_t *p)
{
    return (uint16_t)(p[0] | (p[1] << 8));
}

uint32_t proto_get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

float proto_get_f32(const uint8_t *p)
{
    const uint32_t u = proto_get_u32(p);
    float v;
    memcpy(&v, &u, 4);
    return v;
}

int16_t proto_quantize(float value, float lsb)
{
    const float q = value / lsb;
    if (!(q == q)) return 0;                 /* NaN: the caller validates before sending */
    if (q >= 32767.0f) return 32767;
    if (q <= -32767.0f) return -32767;
    return (int16_t)(q >= 0.0f ? q + 0.5f : q - 0.5f);
}

uint16_t proto_f16(float value)
{
    uint32_t u;
    memcpy(&u, &value, 4);
    const uint16_t sign = (uint16_t)((u >> 16) & 0x8000);
    const int32_t exponent = (int32_t)((u >> 23) & 0xFF) - 127 + 15;
    uint32_t mantissa = u & 0x7FFFFF;
    if (((u >> 23) & 0xFF) == 0xFF) return (uint16_t)(sign | 0x7C00 | (mantissa ? 0x200 : 0));
    if (exponent >= 31) return (uint16_t)(sign | 0x7C00);
    if (exponent <= 0) {
        if (exponent < -10) return sign;
        mantissa |= 0x800000;
        const uint32_t shift = (uint32_t)(14 - exponent);
        uint32_t half = mantissa >> shift;
        if ((mantissa >> (shift - 1)) & 1) half++;
        return (uint16_t)(sign | half);
    }
    uint32_t half = ((uint32_t)exponent << 10) | (mantissa >> 13);
    if (mantissa & 0x1000) half++;  /* round half up; a carry into the exponent is still correct */
    return (uint16_t)(sign | (half > 0x7C00 ? 0x7C00 : half));
}
