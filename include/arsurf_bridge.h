/*
 * arsurf_bridge.h - the arsurf haptic UDP bridge, protocol version 3, for C and C++ clients.
 *
 * One self-contained header (C99 or C++11, no dependency beyond the C library; no OpenSSL):
 * packet layouts and constants, little-endian encoders and decoders that do not depend on the
 * host's byte order or struct packing, SHA-256 (FIPS 180-4) and HMAC-SHA256 (RFC 2104), the
 * client's checks on every FORCE packet, and the session key file reader. A CHAI3D or
 * OpenHaptics program includes it as it is; examples/cpp/arsurf_client.cpp is a complete client.
 *
 * The protocol is docs/bridge-protocol.rst (its test vector is checked by
 * `arsurf_self_test()` and by tests/test_cpp_bridge.py); the server is
 * arsurf/haptics/udp_bridge.py, the reference client in Python arsurf/haptics/client.py.
 * Every field is little-endian, f64 is IEEE-754 binary64, there is no padding: the offsets
 * below are the byte offsets in the datagram. SI units: m, m/s, N, s.
 *
 *   HELLO     client -> server,  72 bytes: header (session zero), t, tag
 *   CHALLENGE server -> client,  72 bytes: header (the session id), ack u64 (the HELLO's number), tag
 *   POSE      client -> server, 156 bytes: header, t, position[3], velocity[3], quaternion[4] (w,x,y,z),
 *             buttons u32, tag
 *   FORCE     server -> client, 112 bytes: header (flags), ack u64, server t, echo, force[3], tag
 *   RELEASE   client -> server,  72 bytes: header, t, tag
 *   header    32 bytes: magic "ARSH", version u8 = 3, type u8, flags u16, sequence number u64,
 *             session id u8[16] (drawn by the server at each open; a client learns it from CHALLENGE)
 *   tag       HMAC-SHA256(key, every byte before the tag), 32 bytes
 *
 * Define ARSURF_BRIDGE_NO_FILES before including it to leave out the key file reader (stdio and,
 * on POSIX, sys/stat.h), e.g. on a microcontroller.
 *
 * Usage (C++):
 *
 *     arsurf_client c;
 *     char err[200];
 *     uint8_t key[ARSURF_KEY_MAX]; size_t keylen;
 *     if (arsurf_read_key_file("bridge.key", key, &keylen, err, sizeof err) != 0) { puts(err); return 2; }
 *     uint64_t now_us = ...;   // wall clock, microseconds since 1970 (std::chrono::system_clock)
 *     arsurf_client_init(&c, key, keylen, now_us, 7.9);         // 7.9 N: the device's limit
 *     uint8_t pkt[ARSURF_POSE_SIZE];
 *     if (!c.have_session) arsurf_client_hello(&c, t, pkt);    // sendto 72 bytes until a CHALLENGE
 *     arsurf_pose p = arsurf_pose_at(t, position, velocity);   // or fill the struct
 *     arsurf_client_pose(&c, &p, pkt);                          // with a session: sendto(sock, pkt, 156, ...)
 *     arsurf_force f;                                           // for each datagram received:
 *     if (arsurf_client_check(&c, data, n, from_server, &f) == ARSURF_OK) apply(f.force);
 *     // ARSURF_CHALLENGE: the session id was taken (c.have_session), nothing to apply
 *
 * MIT licence, like arsurf.
 */
#ifndef ARSURF_BRIDGE_H
#define ARSURF_BRIDGE_H

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#ifdef __cplusplus
extern "C" {
#endif

/* ---------------------------------------------------------------------------------------------
 * constants
 * ------------------------------------------------------------------------------------------- */
#define ARSURF_MAGIC "ARSH"            /* bytes 41 52 53 48 */
#define ARSURF_VERSION 3
#define ARSURF_TYPE_POSE 1
#define ARSURF_TYPE_FORCE 2
#define ARSURF_TYPE_RELEASE 3
#define ARSURF_TYPE_HELLO 4
#define ARSURF_TYPE_CHALLENGE 5
#define ARSURF_FLAG_STALE_INPUT 1u     /* FORCE flags */
#define ARSURF_FLAG_RAMPING 2u
#define ARSURF_FLAG_CLAMPED 4u
#define ARSURF_DEFAULT_PORT 47474
#define ARSURF_MAC_SIZE 32
#define ARSURF_KEY_MIN 16               /* bytes */
#define ARSURF_KEY_MAX 64
#define ARSURF_WINDOW 64                /* accepted sequence numbers remembered below the newest */
#define ARSURF_SESSION_SIZE 16          /* bytes of the session id */

#define ARSURF_HEADER_SIZE 16           /* magic .. sequence number: enough to tell the type */
#define ARSURF_OFF_MAGIC 0
#define ARSURF_OFF_VERSION 4
#define ARSURF_OFF_TYPE 5
#define ARSURF_OFF_FLAGS 6
#define ARSURF_OFF_SEQ 8
#define ARSURF_OFF_SESSION 16           /* every packet; HELLO: 16 zero bytes */

#define ARSURF_POSE_SIZE 156
#define ARSURF_POSE_OFF_T 32
#define ARSURF_POSE_OFF_POSITION 40
#define ARSURF_POSE_OFF_VELOCITY 64
#define ARSURF_POSE_OFF_QUATERNION 88
#define ARSURF_POSE_OFF_BUTTONS 120
#define ARSURF_POSE_OFF_TAG 124

#define ARSURF_FORCE_SIZE 112
#define ARSURF_FORCE_OFF_ACK 32
#define ARSURF_FORCE_OFF_T 40
#define ARSURF_FORCE_OFF_ECHO 48
#define ARSURF_FORCE_OFF_FORCE 56
#define ARSURF_FORCE_OFF_TAG 80

#define ARSURF_RELEASE_SIZE 72
#define ARSURF_RELEASE_OFF_T 32
#define ARSURF_RELEASE_OFF_TAG 40

#define ARSURF_HELLO_SIZE 72            /* the RELEASE layout, session field zero */
#define ARSURF_HELLO_OFF_T 32
#define ARSURF_HELLO_OFF_TAG 40

#define ARSURF_CHALLENGE_SIZE 72        /* never larger than the HELLO it answers */
#define ARSURF_CHALLENGE_OFF_ACK 32
#define ARSURF_CHALLENGE_OFF_TAG 40

#if defined(__cplusplus)
#define ARSURF_INLINE static inline
#elif defined(__STDC_VERSION__) && __STDC_VERSION__ >= 199901L
#define ARSURF_INLINE static inline
#else
#define ARSURF_INLINE static
#endif

/* ---------------------------------------------------------------------------------------------
 * packet contents
 * ------------------------------------------------------------------------------------------- */
typedef struct arsurf_pose {
    double t;              /* client timestamp, s (the client's monotonic clock; strictly increasing) */
    double position[3];    /* stylus position, m */
    double velocity[3];    /* stylus velocity, m/s (all three NaN: the server differentiates) */
    double quaternion[4];  /* orientation w, x, y, z */
    uint32_t buttons;      /* bit 0: first button, bit 1: second */
} arsurf_pose;

typedef struct arsurf_force {
    uint16_t flags;        /* ARSURF_FLAG_* */
    uint64_t seq;          /* the server's sequence number */
    uint8_t session[ARSURF_SESSION_SIZE];  /* the session id */
    uint64_t ack;          /* sequence number of the last POSE the server accepted */
    double t;              /* server timestamp, s */
    double echo;           /* client timestamp of that POSE (NaN if none): round trip = now - echo */
    double force[3];       /* force on the handle, N */
} arsurf_force;

/* Why a datagram was dropped (or ARSURF_OK). The names (arsurf_status_name) are the counters of
 * the Python client (HapticClient.stats) and of the bridge (UdpBridgeDevice.stats). */
typedef enum arsurf_status {
    ARSURF_OK = 0,
    ARSURF_OVERSIZED,
    ARSURF_TRUNCATED,
    ARSURF_FOREIGN,
    ARSURF_BAD_MAGIC,
    ARSURF_BAD_VERSION,
    ARSURF_BAD_TYPE,
    ARSURF_BAD_MAC,
    ARSURF_REPLAYED,
    ARSURF_OUT_OF_ORDER,
    ARSURF_BAD_ACK,
    ARSURF_NONFINITE,
    ARSURF_OVER_LIMIT,
    ARSURF_BAD_SESSION,    /* a FORCE of another session */
    ARSURF_CHALLENGE,      /* not a drop: a CHALLENGE was accepted, the client took its session id */
    ARSURF_N_STATUS
} arsurf_status;

ARSURF_INLINE const char *arsurf_status_name(arsurf_status s) {
    static const char *const names[ARSURF_N_STATUS] = {
        "accepted", "oversized", "truncated", "foreign", "bad_magic", "bad_version", "bad_type", "bad_mac",
        "replayed", "out_of_order", "bad_ack", "nonfinite", "over_limit", "bad_session", "challenges"};
    return ((unsigned)s < (unsigned)ARSURF_N_STATUS) ? names[s] : "unknown";
}

/* ---------------------------------------------------------------------------------------------
 * byte order: explicit little-endian stores and loads, whatever the host
 * ------------------------------------------------------------------------------------------- */
ARSURF_INLINE void arsurf_put_u16(uint8_t *p, uint16_t v) {
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
}
ARSURF_INLINE void arsurf_put_u32(uint8_t *p, uint32_t v) {
    int i;
    for (i = 0; i < 4; ++i) p[i] = (uint8_t)(v >> (8 * i));
}
ARSURF_INLINE void arsurf_put_u64(uint8_t *p, uint64_t v) {
    int i;
    for (i = 0; i < 8; ++i) p[i] = (uint8_t)(v >> (8 * i));
}
ARSURF_INLINE uint16_t arsurf_get_u16(const uint8_t *p) { return (uint16_t)(p[0] | (p[1] << 8)); }
ARSURF_INLINE uint32_t arsurf_get_u32(const uint8_t *p) {
    uint32_t v = 0;
    int i;
    for (i = 3; i >= 0; --i) v = (v << 8) | p[i];
    return v;
}
ARSURF_INLINE uint64_t arsurf_get_u64(const uint8_t *p) {
    uint64_t v = 0;
    int i;
    for (i = 7; i >= 0; --i) v = (v << 8) | p[i];
    return v;
}
/* f64: the IEEE-754 bit pattern as a u64 (assumes the host's double is binary64, as on every
 * platform CHAI3D and OpenHaptics run on; checked at compile time below). */
ARSURF_INLINE uint64_t arsurf_f64_bits(double x) {
    uint64_t u;
    memcpy(&u, &x, 8);
    return u;
}
ARSURF_INLINE double arsurf_f64_from_bits(uint64_t u) {
    double x;
    memcpy(&x, &u, 8);
    return x;
}
ARSURF_INLINE void arsurf_put_f64(uint8_t *p, double x) { arsurf_put_u64(p, arsurf_f64_bits(x)); }
ARSURF_INLINE double arsurf_get_f64(const uint8_t *p) { return arsurf_f64_from_bits(arsurf_get_u64(p)); }
/* finite: exponent bits not all ones (no libm, no <cmath> overload questions) */
ARSURF_INLINE int arsurf_finite(double x) { return ((arsurf_f64_bits(x) >> 52) & 0x7FFu) != 0x7FFu; }

typedef char arsurf_double_is_8_bytes[(sizeof(double) == 8) ? 1 : -1];

/* ---------------------------------------------------------------------------------------------
 * SHA-256 (FIPS 180-4) and HMAC-SHA256 (RFC 2104)
 * ------------------------------------------------------------------------------------------- */
typedef struct arsurf_sha256 {
    uint32_t h[8];
    uint64_t bytes;        /* message length so far */
    uint8_t block[64];
    size_t used;           /* bytes in block */
} arsurf_sha256;

#define ARSURF_ROTR(x, n) (((x) >> (n)) | ((x) << (32 - (n))))

ARSURF_INLINE void arsurf_sha256_compress(uint32_t h[8], const uint8_t b[64]) {
    static const uint32_t k[64] = {
        0x428a2f98u, 0x71374491u, 0xb5c0fbcfu, 0xe9b5dba5u, 0x3956c25bu, 0x59f111f1u, 0x923f82a4u, 0xab1c5ed5u,
        0xd807aa98u, 0x12835b01u, 0x243185beu, 0x550c7dc3u, 0x72be5d74u, 0x80deb1feu, 0x9bdc06a7u, 0xc19bf174u,
        0xe49b69c1u, 0xefbe4786u, 0x0fc19dc6u, 0x240ca1ccu, 0x2de92c6fu, 0x4a7484aau, 0x5cb0a9dcu, 0x76f988dau,
        0x983e5152u, 0xa831c66du, 0xb00327c8u, 0xbf597fc7u, 0xc6e00bf3u, 0xd5a79147u, 0x06ca6351u, 0x14292967u,
        0x27b70a85u, 0x2e1b2138u, 0x4d2c6dfcu, 0x53380d13u, 0x650a7354u, 0x766a0abbu, 0x81c2c92eu, 0x92722c85u,
        0xa2bfe8a1u, 0xa81a664bu, 0xc24b8b70u, 0xc76c51a3u, 0xd192e819u, 0xd6990624u, 0xf40e3585u, 0x106aa070u,
        0x19a4c116u, 0x1e376c08u, 0x2748774cu, 0x34b0bcb5u, 0x391c0cb3u, 0x4ed8aa4au, 0x5b9cca4fu, 0x682e6ff3u,
        0x748f82eeu, 0x78a5636fu, 0x84c87814u, 0x8cc70208u, 0x90befffau, 0xa4506cebu, 0xbef9a3f7u, 0xc67178f2u};
    uint32_t w[64], a, bb, c, d, e, f, g, hh, t1, t2;
    int i;
    for (i = 0; i < 16; ++i)
        w[i] = ((uint32_t)b[4 * i] << 24) | ((uint32_t)b[4 * i + 1] << 16) | ((uint32_t)b[4 * i + 2] << 8) |
               (uint32_t)b[4 * i + 3];
    for (i = 16; i < 64; ++i) {
        uint32_t s0 = ARSURF_ROTR(w[i - 15], 7) ^ ARSURF_ROTR(w[i - 15], 18) ^ (w[i - 15] >> 3);
        uint32_t s1 = ARSURF_ROTR(w[i - 2], 17) ^ ARSURF_ROTR(w[i - 2], 19) ^ (w[i - 2] >> 10);
        w[i] = w[i - 16] + s0 + w[i - 7] + s1;
    }
    a = h[0]; bb = h[1]; c = h[2]; d = h[3]; e = h[4]; f = h[5]; g = h[6]; hh = h[7];
    for (i = 0; i < 64; ++i) {
        t1 = hh + (ARSURF_ROTR(e, 6) ^ ARSURF_ROTR(e, 11) ^ ARSURF_ROTR(e, 25)) + ((e & f) ^ (~e & g)) + k[i] + w[i];
        t2 = (ARSURF_ROTR(a, 2) ^ ARSURF_ROTR(a, 13) ^ ARSURF_ROTR(a, 22)) + ((a & bb) ^ (a & c) ^ (bb & c));
        hh = g; g = f; f = e; e = d + t1; d = c; c = bb; bb = a; a = t1 + t2;
    }
    h[0] += a; h[1] += bb; h[2] += c; h[3] += d; h[4] += e; h[5] += f; h[6] += g; h[7] += hh;
}

ARSURF_INLINE void arsurf_sha256_init(arsurf_sha256 *s) {
    static const uint32_t h0[8] = {0x6a09e667u, 0xbb67ae85u, 0x3c6ef372u, 0xa54ff53au,
                                   0x510e527fu, 0x9b05688cu, 0x1f83d9abu, 0x5be0cd19u};
    memcpy(s->h, h0, sizeof h0);
    s->bytes = 0;
    s->used = 0;
}

ARSURF_INLINE void arsurf_sha256_update(arsurf_sha256 *s, const void *data, size_t len) {
    const uint8_t *p = (const uint8_t *)data;
    s->bytes += len;
    while (len > 0) {
        size_t take = 64 - s->used;
        if (take > len) take = len;
        memcpy(s->block + s->used, p, take);
        s->used += take;
        p += take;
        len -= take;
        if (s->used == 64) {
            arsurf_sha256_compress(s->h, s->block);
            s->used = 0;
        }
    }
}

ARSURF_INLINE void arsurf_sha256_final(arsurf_sha256 *s, uint8_t out[32]) {
    uint64_t bits = s->bytes * 8u;
    int i;
    s->block[s->used++] = 0x80;
    if (s->used > 56) {
        memset(s->block + s->used, 0, 64 - s->used);
        arsurf_sha256_compress(s->h, s->block);
        s->used = 0;
    }
    memset(s->block + s->used, 0, 56 - s->used);
    for (i = 0; i < 8; ++i) s->block[56 + i] = (uint8_t)(bits >> (56 - 8 * i));  /* big-endian length */
    arsurf_sha256_compress(s->h, s->block);
    for (i = 0; i < 8; ++i) {
        out[4 * i] = (uint8_t)(s->h[i] >> 24);
        out[4 * i + 1] = (uint8_t)(s->h[i] >> 16);
        out[4 * i + 2] = (uint8_t)(s->h[i] >> 8);
        out[4 * i + 3] = (uint8_t)s->h[i];
    }
}

/* HMAC-SHA256(key, msg) (RFC 2104): H((K ^ opad) || H((K ^ ipad) || msg)), K padded to 64 bytes
 * (a key longer than the block is hashed first). Any key length works here; the protocol uses
 * 16 to 64 bytes. */
ARSURF_INLINE void arsurf_hmac_sha256(const uint8_t *key, size_t keylen, const uint8_t *msg, size_t len,
                                      uint8_t out[32]) {
    uint8_t k[64], pad[64], inner[32];
    arsurf_sha256 s;
    int i;
    memset(k, 0, sizeof k);
    if (keylen > 64) {
        arsurf_sha256_init(&s);
        arsurf_sha256_update(&s, key, keylen);
        arsurf_sha256_final(&s, k);
    } else if (keylen > 0) {
        memcpy(k, key, keylen);
    }
    for (i = 0; i < 64; ++i) pad[i] = (uint8_t)(k[i] ^ 0x36u);
    arsurf_sha256_init(&s);
    arsurf_sha256_update(&s, pad, 64);
    arsurf_sha256_update(&s, msg, len);
    arsurf_sha256_final(&s, inner);
    for (i = 0; i < 64; ++i) pad[i] = (uint8_t)(k[i] ^ 0x5cu);
    arsurf_sha256_init(&s);
    arsurf_sha256_update(&s, pad, 64);
    arsurf_sha256_update(&s, inner, 32);
    arsurf_sha256_final(&s, out);
}

/* Equal in constant time (no early exit): compare tags with this, never with memcmp. */
ARSURF_INLINE int arsurf_equal_ct(const uint8_t *a, const uint8_t *b, size_t n) {
    volatile uint8_t diff = 0;
    size_t i;
    for (i = 0; i < n; ++i) diff |= (uint8_t)(a[i] ^ b[i]);
    return diff == 0;
}

/* ---------------------------------------------------------------------------------------------
 * packets
 * ------------------------------------------------------------------------------------------- */
/* The 32-byte header; `session` NULL: 16 zero bytes (a HELLO). */
ARSURF_INLINE void arsurf_put_header(uint8_t *p, int type, uint16_t flags, uint64_t seq, const uint8_t *session) {
    memcpy(p + ARSURF_OFF_MAGIC, ARSURF_MAGIC, 4);
    p[ARSURF_OFF_VERSION] = ARSURF_VERSION;
    p[ARSURF_OFF_TYPE] = (uint8_t)type;
    arsurf_put_u16(p + ARSURF_OFF_FLAGS, flags);
    arsurf_put_u64(p + ARSURF_OFF_SEQ, seq);
    if (session)
        memcpy(p + ARSURF_OFF_SESSION, session, ARSURF_SESSION_SIZE);
    else
        memset(p + ARSURF_OFF_SESSION, 0, ARSURF_SESSION_SIZE);
}

/* Append the tag of the first `body` bytes of `p` at p + body. */
ARSURF_INLINE void arsurf_tag(const uint8_t *key, size_t keylen, uint8_t *p, size_t body) {
    arsurf_hmac_sha256(key, keylen, p, body, p + body);
}

ARSURF_INLINE int arsurf_tag_ok(const uint8_t *key, size_t keylen, const uint8_t *p, size_t body) {
    uint8_t tag[32];
    arsurf_hmac_sha256(key, keylen, p, body, tag);
    return arsurf_equal_ct(tag, p + body, 32);
}

/* A pose with no known velocity (NaN: the server differentiates), identity orientation, no button. */
ARSURF_INLINE arsurf_pose arsurf_pose_at(double t, const double position[3], const double *velocity) {
    arsurf_pose p;
    int i;
    double nan = arsurf_f64_from_bits(0x7FF8000000000000ull);
    p.t = t;
    for (i = 0; i < 3; ++i) {
        p.position[i] = position[i];
        p.velocity[i] = velocity ? velocity[i] : nan;
    }
    p.quaternion[0] = 1.0;
    p.quaternion[1] = p.quaternion[2] = p.quaternion[3] = 0.0;
    p.buttons = 0;
    return p;
}

ARSURF_INLINE void arsurf_encode_pose(const uint8_t *key, size_t keylen, uint64_t seq, const uint8_t *session,
                                      const arsurf_pose *pose, uint8_t out[ARSURF_POSE_SIZE]) {
    int i;
    arsurf_put_header(out, ARSURF_TYPE_POSE, 0, seq, session);
    arsurf_put_f64(out + ARSURF_POSE_OFF_T, pose->t);
    for (i = 0; i < 3; ++i) {
        arsurf_put_f64(out + ARSURF_POSE_OFF_POSITION + 8 * i, pose->position[i]);
        arsurf_put_f64(out + ARSURF_POSE_OFF_VELOCITY + 8 * i, pose->velocity[i]);
    }
    for (i = 0; i < 4; ++i) arsurf_put_f64(out + ARSURF_POSE_OFF_QUATERNION + 8 * i, pose->quaternion[i]);
    arsurf_put_u32(out + ARSURF_POSE_OFF_BUTTONS, pose->buttons);
    arsurf_tag(key, keylen, out, ARSURF_POSE_OFF_TAG);
}

ARSURF_INLINE void arsurf_encode_release(const uint8_t *key, size_t keylen, uint64_t seq, const uint8_t *session,
                                         double t, uint8_t out[ARSURF_RELEASE_SIZE]) {
    arsurf_put_header(out, ARSURF_TYPE_RELEASE, 0, seq, session);
    arsurf_put_f64(out + ARSURF_RELEASE_OFF_T, t);
    arsurf_tag(key, keylen, out, ARSURF_RELEASE_OFF_TAG);
}

/* A HELLO: the client asks for the session id. */
ARSURF_INLINE void arsurf_encode_hello(const uint8_t *key, size_t keylen, uint64_t seq, double t,
                                       uint8_t out[ARSURF_HELLO_SIZE]) {
    arsurf_put_header(out, ARSURF_TYPE_HELLO, 0, seq, NULL);
    arsurf_put_f64(out + ARSURF_HELLO_OFF_T, t);
    arsurf_tag(key, keylen, out, ARSURF_HELLO_OFF_TAG);
}

/* The server's answer to the HELLO numbered `ack` (for simulators and tests). */
ARSURF_INLINE void arsurf_encode_challenge(const uint8_t *key, size_t keylen, uint64_t seq, uint64_t ack,
                                           const uint8_t *session, uint8_t out[ARSURF_CHALLENGE_SIZE]) {
    arsurf_put_header(out, ARSURF_TYPE_CHALLENGE, 0, seq, session);
    arsurf_put_u64(out + ARSURF_CHALLENGE_OFF_ACK, ack);
    arsurf_tag(key, keylen, out, ARSURF_CHALLENGE_OFF_TAG);
}

/* The server's packet (for simulators and tests; a client never sends it). */
ARSURF_INLINE void arsurf_encode_force(const uint8_t *key, size_t keylen, const arsurf_force *f,
                                       uint8_t out[ARSURF_FORCE_SIZE]) {
    int i;
    arsurf_put_header(out, ARSURF_TYPE_FORCE, f->flags, f->seq, f->session);
    arsurf_put_u64(out + ARSURF_FORCE_OFF_ACK, f->ack);
    arsurf_put_f64(out + ARSURF_FORCE_OFF_T, f->t);
    arsurf_put_f64(out + ARSURF_FORCE_OFF_ECHO, f->echo);
    for (i = 0; i < 3; ++i) arsurf_put_f64(out + ARSURF_FORCE_OFF_FORCE + 8 * i, f->force[i]);
    arsurf_tag(key, keylen, out, ARSURF_FORCE_OFF_TAG);
}

/* Size, header and tag of a datagram that must be a packet of `type` and `size` bytes (the tag
 * is its last 32 bytes), in the protocol's order of checks. */
ARSURF_INLINE arsurf_status arsurf_check_packet(const uint8_t *key, size_t keylen, const uint8_t *data, size_t len,
                                                int type, size_t size) {
    if (len > size) return ARSURF_OVERSIZED;
    if (len < ARSURF_HEADER_SIZE) return ARSURF_TRUNCATED;
    if (memcmp(data, ARSURF_MAGIC, 4) != 0) return ARSURF_BAD_MAGIC;
    if (data[ARSURF_OFF_VERSION] != ARSURF_VERSION) return ARSURF_BAD_VERSION;
    if (data[ARSURF_OFF_TYPE] != type) return ARSURF_BAD_TYPE;
    if (len != size) return ARSURF_TRUNCATED;
    if (!arsurf_tag_ok(key, keylen, data, size - ARSURF_MAC_SIZE)) return ARSURF_BAD_MAC;
    return ARSURF_OK;
}

/* Format and tag of a FORCE datagram of `len` bytes (the checks 1, 3 and 4 of the protocol's
 * "What the client must do", without the sender address); fills `out` when ARSURF_OK. */
ARSURF_INLINE arsurf_status arsurf_decode_force(const uint8_t *key, size_t keylen, const uint8_t *data, size_t len,
                                                arsurf_force *out) {
    int i;
    arsurf_status st = arsurf_check_packet(key, keylen, data, len, ARSURF_TYPE_FORCE, ARSURF_FORCE_SIZE);
    if (st != ARSURF_OK) return st;
    out->flags = arsurf_get_u16(data + ARSURF_OFF_FLAGS);
    out->seq = arsurf_get_u64(data + ARSURF_OFF_SEQ);
    memcpy(out->session, data + ARSURF_OFF_SESSION, ARSURF_SESSION_SIZE);
    out->ack = arsurf_get_u64(data + ARSURF_FORCE_OFF_ACK);
    out->t = arsurf_get_f64(data + ARSURF_FORCE_OFF_T);
    out->echo = arsurf_get_f64(data + ARSURF_FORCE_OFF_ECHO);
    for (i = 0; i < 3; ++i) out->force[i] = arsurf_get_f64(data + ARSURF_FORCE_OFF_FORCE + 8 * i);
    return ARSURF_OK;
}

/* Format and tag of a POSE (for simulators of the server and tests); `*seq` receives its number,
 * `session` (ARSURF_SESSION_SIZE bytes, or NULL) its session id. */
ARSURF_INLINE arsurf_status arsurf_decode_pose(const uint8_t *key, size_t keylen, const uint8_t *data, size_t len,
                                               uint64_t *seq, uint8_t *session, arsurf_pose *out) {
    int i;
    arsurf_status st = arsurf_check_packet(key, keylen, data, len, ARSURF_TYPE_POSE, ARSURF_POSE_SIZE);
    if (st != ARSURF_OK) return st;
    *seq = arsurf_get_u64(data + ARSURF_OFF_SEQ);
    if (session) memcpy(session, data + ARSURF_OFF_SESSION, ARSURF_SESSION_SIZE);
    out->t = arsurf_get_f64(data + ARSURF_POSE_OFF_T);
    for (i = 0; i < 3; ++i) {
        out->position[i] = arsurf_get_f64(data + ARSURF_POSE_OFF_POSITION + 8 * i);
        out->velocity[i] = arsurf_get_f64(data + ARSURF_POSE_OFF_VELOCITY + 8 * i);
    }
    for (i = 0; i < 4; ++i) out->quaternion[i] = arsurf_get_f64(data + ARSURF_POSE_OFF_QUATERNION + 8 * i);
    out->buttons = arsurf_get_u32(data + ARSURF_POSE_OFF_BUTTONS);
    return ARSURF_OK;
}

/* ---------------------------------------------------------------------------------------------
 * the client: sequence numbers, and every check before a force reaches a motor
 * ------------------------------------------------------------------------------------------- */
typedef struct arsurf_client {
    uint8_t key[ARSURF_KEY_MAX];
    size_t keylen;
    double max_force;      /* N: a FORCE above it is dropped (ARSURF_OVER_LIMIT), not clamped */
    uint64_t seq;          /* the last sequence number sent */
    uint64_t first_seq;    /* the first one this client sent (acks below it are an earlier run's) */
    int have_rx;           /* a FORCE was accepted */
    uint64_t rx_seq;       /* the newest accepted FORCE sequence number */
    uint64_t rx_seen;      /* bit k: rx_seq - k was accepted */
    int have_session;      /* a CHALLENGE was accepted: `session` holds the server's session id */
    uint8_t session[ARSURF_SESSION_SIZE];
    unsigned long counts[ARSURF_N_STATUS];  /* datagrams by verdict; counts[ARSURF_OK] = accepted */
} arsurf_client;

/* Start a client. `start_seq`: its sequence numbers are start_seq + 1, + 2, ... (use the wall
 * clock in microseconds since 1970: numbers must grow across restarts under one key). Returns 0, or -1 for
 * a key outside 16..64 bytes or a max_force that is not a positive finite number. */
ARSURF_INLINE int arsurf_client_init(arsurf_client *c, const uint8_t *key, size_t keylen, uint64_t start_seq,
                                     double max_force) {
    memset(c, 0, sizeof *c);
    if (keylen < ARSURF_KEY_MIN || keylen > ARSURF_KEY_MAX) return -1;
    if (!(max_force > 0.0) || !arsurf_finite(max_force)) return -1;
    memcpy(c->key, key, keylen);
    c->keylen = keylen;
    c->max_force = max_force;
    c->seq = start_seq;
    c->first_seq = start_seq + 1;
    return 0;
}

/* Encode a HELLO (72 bytes; its sequence number is returned): ask the server for its session id.
 * Send it until arsurf_client_check reports ARSURF_CHALLENGE (then c->have_session is set), and
 * again (once per timeout) when no valid FORCE arrives for a while: the server may have restarted. */
ARSURF_INLINE uint64_t arsurf_client_hello(arsurf_client *c, double t, uint8_t out[ARSURF_HELLO_SIZE]) {
    c->seq += 1;
    arsurf_encode_hello(c->key, c->keylen, c->seq, t, out);
    return c->seq;
}

/* Encode the next POSE of the session (its sequence number is returned); 0 and nothing encoded
 * while the client has no session (send arsurf_client_hello first). */
ARSURF_INLINE uint64_t arsurf_client_pose(arsurf_client *c, const arsurf_pose *pose, uint8_t out[ARSURF_POSE_SIZE]) {
    if (!c->have_session) return 0;
    c->seq += 1;
    arsurf_encode_pose(c->key, c->keylen, c->seq, c->session, pose, out);
    return c->seq;
}

/* Encode a RELEASE (72 bytes): this client is done, the server unpins it; 0 without a session. */
ARSURF_INLINE uint64_t arsurf_client_release(arsurf_client *c, double t, uint8_t out[ARSURF_RELEASE_SIZE]) {
    if (!c->have_session) return 0;
    c->seq += 1;
    arsurf_encode_release(c->key, c->keylen, c->seq, c->session, t, out);
    return c->seq;
}

/* Every check of docs/bridge-protocol.rst "What the client must do with a datagram", in its order:
 * size, sender (`from_server`: the datagram came from the server's address and port), format
 * (FORCE or CHALLENGE), tag, sequence number (replay window of 64, shared by both types), ack
 * among this client's packets; then a CHALLENGE gives the session id (ARSURF_CHALLENGE, nothing
 * to apply) and a FORCE is checked for the session, finite values and the force limit.
 * ARSURF_OK: `out` holds a force that may be applied until the next accepted one (apply zero
 * when none was accepted for a while: the Python client waits 0.1 s). The verdict is counted in
 * c->counts. */
ARSURF_INLINE arsurf_status arsurf_client_check(arsurf_client *c, const uint8_t *data, size_t len, int from_server,
                                                arsurf_force *out) {
    arsurf_status st;
    arsurf_force f;
    uint64_t seq, ack, d;
    double norm2, limit;
    int i, type = 0;
    size_t size = 0;
    if (len > ARSURF_FORCE_SIZE) {
        st = ARSURF_OVERSIZED;
    } else if (!from_server) {
        st = ARSURF_FOREIGN;
    } else if (len < ARSURF_HEADER_SIZE) {
        st = ARSURF_TRUNCATED;
    } else if (memcmp(data, ARSURF_MAGIC, 4) != 0) {
        st = ARSURF_BAD_MAGIC;
    } else if (data[ARSURF_OFF_VERSION] != ARSURF_VERSION) {
        st = ARSURF_BAD_VERSION;
    } else if ((type = data[ARSURF_OFF_TYPE]) != ARSURF_TYPE_FORCE && type != ARSURF_TYPE_CHALLENGE) {
        st = ARSURF_BAD_TYPE;
    } else if (len != (size = (type == ARSURF_TYPE_FORCE) ? ARSURF_FORCE_SIZE : ARSURF_CHALLENGE_SIZE)) {
        st = len < size ? ARSURF_TRUNCATED : ARSURF_OVERSIZED;
    } else if (!arsurf_tag_ok(c->key, c->keylen, data, size - ARSURF_MAC_SIZE)) {
        st = ARSURF_BAD_MAC;
    } else if (c->have_rx && (seq = arsurf_get_u64(data + ARSURF_OFF_SEQ)) <= c->rx_seq) {
        d = c->rx_seq - seq;
        st = (d < ARSURF_WINDOW && ((c->rx_seen >> d) & 1u)) ? ARSURF_REPLAYED : ARSURF_OUT_OF_ORDER;
    } else if ((ack = arsurf_get_u64(data + ARSURF_FORCE_OFF_ACK)) < c->first_seq || ack > c->seq) {
        st = ARSURF_BAD_ACK;  /* (the ack is at offset 32 in both types) */
    } else if (type == ARSURF_TYPE_CHALLENGE) {
        st = ARSURF_CHALLENGE;
    } else if (arsurf_decode_force(c->key, c->keylen, data, len, &f) != ARSURF_OK) {
        st = ARSURF_BAD_MAC;  /* cannot happen: format and tag were checked above */
    } else if (c->have_session == 0 || memcmp(f.session, c->session, ARSURF_SESSION_SIZE) != 0) {
        st = ARSURF_BAD_SESSION;
    } else if (!arsurf_finite(f.force[0]) || !arsurf_finite(f.force[1]) || !arsurf_finite(f.force[2]) ||
               !arsurf_finite(f.t)) {
        st = ARSURF_NONFINITE;
    } else {
        norm2 = 0.0;  /* the sum in the Python client's order: ((0 + x^2) + y^2) + z^2 */
        for (i = 0; i < 3; ++i) norm2 += f.force[i] * f.force[i];
        limit = c->max_force * (1.0 + 1e-9);
        st = (sqrt(norm2) > limit) ? ARSURF_OVER_LIMIT : ARSURF_OK;
    }
    if (st == ARSURF_OK || st == ARSURF_CHALLENGE) {
        seq = arsurf_get_u64(data + ARSURF_OFF_SEQ);
        d = c->have_rx ? seq - c->rx_seq : ARSURF_WINDOW;
        c->rx_seen = (d < ARSURF_WINDOW) ? ((c->rx_seen << d) | 1u) : 1u;
        c->rx_seq = seq;
        c->have_rx = 1;
        if (st == ARSURF_CHALLENGE) {
            memcpy(c->session, data + ARSURF_OFF_SESSION, ARSURF_SESSION_SIZE);
            c->have_session = 1;
        } else {
            *out = f;
        }
    }
    c->counts[st] += 1;
    return st;
}

/* Datagrams dropped, all reasons. */
ARSURF_INLINE unsigned long arsurf_client_dropped(const arsurf_client *c) {
    unsigned long n = 0;
    int i;
    for (i = 1; i < ARSURF_CHALLENGE; ++i) n += c->counts[i];
    return n;
}

/* ---------------------------------------------------------------------------------------------
 * keys
 * ------------------------------------------------------------------------------------------- */
ARSURF_INLINE int arsurf_hex_digit(int ch) {
    if (ch >= '0' && ch <= '9') return ch - '0';
    if (ch >= 'a' && ch <= 'f') return ch - 'a' + 10;
    if (ch >= 'A' && ch <= 'F') return ch - 'A' + 10;
    return -1;
}

/* The key written as hex text (32 to 128 digits; surrounding whitespace ignored). Returns 0, or
 * -1 (not hex, odd length, or not 16..64 bytes); `key` needs ARSURF_KEY_MAX bytes. */
ARSURF_INLINE int arsurf_key_from_hex(const char *text, size_t len, uint8_t *key, size_t *keylen) {
    size_t a = 0, b = len, i, n;
    while (a < b && (text[a] == ' ' || text[a] == '\t' || text[a] == '\n' || text[a] == '\r')) ++a;
    while (b > a && (text[b - 1] == ' ' || text[b - 1] == '\t' || text[b - 1] == '\n' || text[b - 1] == '\r')) --b;
    n = b - a;
    if (n % 2 != 0 || n / 2 < ARSURF_KEY_MIN || n / 2 > ARSURF_KEY_MAX) return -1;
    for (i = 0; i < n / 2; ++i) {
        int hi = arsurf_hex_digit((unsigned char)text[a + 2 * i]), lo = arsurf_hex_digit((unsigned char)text[a + 2 * i + 1]);
        if (hi < 0 || lo < 0) return -1;
        key[i] = (uint8_t)(hi * 16 + lo);
    }
    *keylen = n / 2;
    return 0;
}

#ifndef ARSURF_BRIDGE_NO_FILES
#include <stdio.h>
#if defined(__unix__) || defined(__APPLE__)
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#define ARSURF_HAVE_POSIX_FILES 1
#ifdef O_NOFOLLOW
#define ARSURF_O_NOFOLLOW O_NOFOLLOW
#else
#define ARSURF_O_NOFOLLOW 0
#endif
#endif

#ifdef ARSURF_HAVE_POSIX_FILES
/* 0 if the folder holding `path` may hold a key file (as ssh judges it): owned by this user or
 * root and writable by its owner only; else -1 with a one-line reason in `err`. */
ARSURF_INLINE int arsurf_check_key_folder(const char *path, char *err, size_t errlen) {
    char folder[4096];
    size_t n = strlen(path), cut;
    struct stat st;
    if (n >= sizeof folder) {
        snprintf(err, errlen, "the key file path is longer than %u bytes", (unsigned)(sizeof folder - 1));
        return -1;
    }
    memcpy(folder, path, n + 1);
    cut = n;
    while (cut > 0 && folder[cut - 1] != '/') --cut;  /* the folder: up to the last '/' */
    if (cut == 0) {
        folder[0] = '.';
        folder[1] = '\0';
    } else {
        folder[cut > 1 ? cut - 1 : 1] = '\0';  /* "/k" -> "/" */
    }
    if (stat(folder, &st) != 0) {
        snprintf(err, errlen, "cannot read the folder %s of the key file %s", folder, path);
        return -1;
    }
    if ((st.st_uid != geteuid() && st.st_uid != 0) || (st.st_mode & 022)) {
        snprintf(err, errlen, "the key file %s is in a folder other users own or can write to (%s, uid %lu, mode "
                 "%03o): someone else could have planted it; keep key files in a folder of your own",
                 path, folder, (unsigned long)st.st_uid, (unsigned)(st.st_mode & 0777));
        return -1;
    }
    return 0;
}
#endif

/* Read the session key file arsurf wrote (one line of hex). Refused, with a one-line message in
 * `err`, if it cannot be read, is not a regular file, is longer than 4096 bytes or is not a key,
 * and (POSIX, as arsurf and ssh refuse it) if it is a symbolic link, is owned by another user, other
 * users may read or write it, or its folder is owned by another user or writable by others
 * (someone else could have planted it). The checks are made on the opened file, which is opened
 * without blocking (a FIFO cannot hang the client). A link is refused where O_NOFOLLOW is
 * visible (C++, gnu99, or -std=c99 with _POSIX_C_SOURCE 200809L defined before any include);
 * elsewhere it is followed and its target judged by the same rules. Returns 0 or -1. */
ARSURF_INLINE int arsurf_read_key_file(const char *path, uint8_t *key, size_t *keylen, char *err, size_t errlen) {
    char text[4097];
    size_t n = 0;
#ifdef ARSURF_HAVE_POSIX_FILES
    struct stat st;
    ssize_t got;
    int fd = open(path, O_RDONLY | O_NONBLOCK | ARSURF_O_NOFOLLOW);
    if (fd < 0) {
        snprintf(err, errlen, "cannot read the key file %s (missing, unreadable or a symbolic link)", path);
        return -1;
    }
    if (fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
        close(fd);
        snprintf(err, errlen, "the key file %s is not a regular file", path);
        return -1;
    }
    if (st.st_uid != geteuid()) {
        close(fd);
        snprintf(err, errlen, "the key file %s is owned by uid %lu, not by you (uid %lu): someone else may have "
                 "planted it", path, (unsigned long)st.st_uid, (unsigned long)geteuid());
        return -1;
    }
    if (st.st_mode & 077) {
        close(fd);
        snprintf(err, errlen, "the key file %s is accessible to other users; make it owner-only: chmod 600 %s", path, path);
        return -1;
    }
    if (arsurf_check_key_folder(path, err, errlen) != 0) {
        close(fd);
        return -1;
    }
    while (n < sizeof text && (got = read(fd, text + n, sizeof text - n)) > 0) n += (size_t)got;
    close(fd);
#else
    FILE *fh = fopen(path, "rb");
    if (!fh) {
        snprintf(err, errlen, "cannot read the key file %s", path);
        return -1;
    }
    n = fread(text, 1, sizeof text, fh);
    fclose(fh);
#endif
    if (n > 4096) {
        snprintf(err, errlen, "the key file %s is longer than 4096 bytes; a key file is one line of hex", path);
        return -1;
    }
    if (arsurf_key_from_hex(text, n, key, keylen) != 0) {
        snprintf(err, errlen, "the key file %s does not hold a key (32 to 128 hex digits)", path);
        return -1;
    }
    return 0;
}
#endif /* ARSURF_BRIDGE_NO_FILES */

/* ---------------------------------------------------------------------------------------------
 * self-test: the test vector of docs/bridge-protocol.rst
 * ------------------------------------------------------------------------------------------- */
ARSURF_INLINE int arsurf_hex_equal(const uint8_t *bytes, const char *hex, size_t n) {
    size_t i;
    for (i = 0; i < n; ++i)
        if (bytes[i] != (uint8_t)(arsurf_hex_digit(hex[2 * i]) * 16 + arsurf_hex_digit(hex[2 * i + 1]))) return 0;
    return 1;
}

/* 0 if SHA-256, HMAC-SHA256 and the five packets of the documented test vector come out right on
 * this compiler and platform, else the number of the first failing check. */
ARSURF_INLINE int arsurf_self_test(void) {
    uint8_t key[32], session[ARSURF_SESSION_SIZE], out[ARSURF_POSE_SIZE], digest[32];
    arsurf_sha256 s;
    arsurf_pose p;
    arsurf_force f, g;
    int i;
    static const double pos[3] = {0.001, -0.002, 0.003}, vel[3] = {0.0, 0.0, 0.0};
    for (i = 0; i < 32; ++i) key[i] = (uint8_t)i;
    for (i = 0; i < ARSURF_SESSION_SIZE; ++i) session[i] = (uint8_t)(0xF0 + i);
    arsurf_sha256_init(&s);  /* FIPS 180-4 example: SHA-256("abc") */
    arsurf_sha256_update(&s, "abc", 3);
    arsurf_sha256_final(&s, digest);
    if (!arsurf_hex_equal(digest, "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad", 32)) return 1;
    /* RFC 4231 test case 2 */
    arsurf_hmac_sha256((const uint8_t *)"Jefe", 4, (const uint8_t *)"what do ya want for nothing?", 28, digest);
    if (!arsurf_hex_equal(digest, "5bdcc146bf60754e6a042426089575c75a003f089d2739839dec58b964ec3843", 32)) return 2;
    p = arsurf_pose_at(0.5, pos, vel);
    p.buttons = 1;
    arsurf_encode_pose(key, 32, 2, session, &p, out);
    if (!arsurf_hex_equal(out, "41525348030100000200000000000000f0f1f2f3f4f5f6f7", 24)) return 3;
    if (!arsurf_hex_equal(out + ARSURF_POSE_OFF_TAG,
                          "e827ffe0a28c45df992408ed75caa7d4a0af4d67a8924db5b4c11c07dd3bbbe7", 32)) return 4;
    f.flags = 0; f.seq = 3; f.ack = 2; f.t = 1.25; f.echo = 0.5;
    memcpy(f.session, session, ARSURF_SESSION_SIZE);
    f.force[0] = 0.0; f.force[1] = 0.0; f.force[2] = 1.5;
    arsurf_encode_force(key, 32, &f, out);
    if (!arsurf_hex_equal(out + ARSURF_FORCE_OFF_TAG,
                          "c1c10812f20635fa1868cc48f8b8080d92e30a7b360781d424d24d649b78dbe6", 32)) return 5;
    if (arsurf_decode_force(key, 32, out, ARSURF_FORCE_SIZE, &g) != ARSURF_OK || g.force[2] != 1.5 || g.ack != 2 ||
        memcmp(g.session, session, ARSURF_SESSION_SIZE) != 0)
        return 6;
    out[56] ^= 1u;  /* one flipped bit */
    if (arsurf_decode_force(key, 32, out, ARSURF_FORCE_SIZE, &g) != ARSURF_BAD_MAC) return 7;
    arsurf_encode_release(key, 32, 3, session, 0.75, out);
    if (!arsurf_hex_equal(out + ARSURF_RELEASE_OFF_TAG,
                          "737c550339b040b0c80177af8fe6411cd78739810a1acb38612346e2b162d766", 32)) return 8;
    arsurf_encode_hello(key, 32, 1, 0.25, out);
    if (!arsurf_hex_equal(out + ARSURF_HELLO_OFF_TAG,
                          "ef2e42d4f2175fe0f46a6bb9106e4b8a616dda33e9d7e6839070881505b7f6be", 32)) return 9;
    arsurf_encode_challenge(key, 32, 2, 1, session, out);
    if (!arsurf_hex_equal(out + ARSURF_CHALLENGE_OFF_TAG,
                          "a80dcfc2f79f932cc80827bb4cf992cf68eeaa1ee00a54c6fc147ea8ef7de41b", 32)) return 10;
    return 0;
}

#ifdef __cplusplus
}
#endif

#endif /* ARSURF_BRIDGE_H */
