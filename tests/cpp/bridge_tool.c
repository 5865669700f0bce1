/* bridge_tool.c - include/arsurf_bridge.h driven line by line from stdin, for tests/test_cpp_bridge.py.
 *
 * Compiled as C99 (the header must be plain C too). Doubles travel as the 16 hex digits of their
 * IEEE-754 bits (exact, NaN payloads and -0.0 included); byte strings as hex ("-": empty).
 *
 *   bridge_tool vector            the five packets of the documented test vector, "name HEX" per line
 *   bridge_tool hmac              "KEYHEX MSGHEX" -> the HMAC-SHA256 tag
 *   bridge_tool encode            "pose KEY SEQ SESSION T PX PY PZ VX VY VZ QW QX QY QZ BUTTONS"
 *                                 "release KEY SEQ SESSION T" | "hello KEY SEQ T" | "challenge KEY SEQ ACK SESSION"
 *                                 "force KEY SEQ SESSION ACK T ECHO FX FY FZ FLAGS" -> packet
 *   bridge_tool check             first "client KEY START_SEQ HELLOS_SENT MAX_FORCE", then per line
 *                                 "poses N" (N poses sent, with the session taken) -> "SEQ" of the last,
 *                                 "FROM_SERVER HEX" -> "STATUS" (+ " FX FY FZ" when accepted)
 *   bridge_tool keyfile           "PATH" -> "ok KEYHEX" or "error MESSAGE" (arsurf_read_key_file)
 */
#define _POSIX_C_SOURCE 200809L /* O_NOFOLLOW under -std=c99: a key file that is a link is refused */
#include "arsurf_bridge.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define MAXBYTES 8192

static char line[4 * MAXBYTES];

static size_t unhex(const char *s, uint8_t *out) {
    size_t n = 0;
    if (strcmp(s, "-") == 0) return 0;
    while (s[0] && s[1] && n < MAXBYTES) {
        out[n++] = (uint8_t)(arsurf_hex_digit(s[0]) * 16 + arsurf_hex_digit(s[1]));
        s += 2;
    }
    return n;
}

static void puthex(const uint8_t *p, size_t n) {
    size_t i;
    for (i = 0; i < n; ++i) printf("%02x", p[i]);
}

static double f64(const char *s) { return arsurf_f64_from_bits((uint64_t)strtoull(s, NULL, 16)); }
static uint64_t u64(const char *s) { return (uint64_t)strtoull(s, NULL, 10); }

static int split(char *s, char **tok, int max) {
    int n = 0;
    char *p = strtok(s, " \t\r\n");
    while (p && n < max) {
        tok[n++] = p;
        p = strtok(NULL, " \t\r\n");
    }
    return n;
}

int main(int argc, char **argv) {
    static uint8_t key[MAXBYTES], msg[MAXBYTES], out[MAXBYTES], sess[MAXBYTES];
    char *tok[32];
    const char *mode = argc > 1 ? argv[1] : "";
    arsurf_client client;
    int have_client = 0;
    if (strcmp(mode, "vector") == 0) {
        static const double pos[3] = {0.001, -0.002, 0.003}, vel[3] = {0.0, 0.0, 0.0};
        arsurf_pose p = arsurf_pose_at(0.5, pos, vel);
        arsurf_force f;
        uint8_t session[ARSURF_SESSION_SIZE];
        size_t i;
        for (i = 0; i < 32; ++i) key[i] = (uint8_t)i;
        for (i = 0; i < ARSURF_SESSION_SIZE; ++i) session[i] = (uint8_t)(0xF0 + i);
        arsurf_encode_hello(key, 32, 1, 0.25, out);
        printf("hello ");
        puthex(out, ARSURF_HELLO_SIZE);
        arsurf_encode_challenge(key, 32, 2, 1, session, out);
        printf("\nchallenge ");
        puthex(out, ARSURF_CHALLENGE_SIZE);
        p.buttons = 1;
        arsurf_encode_pose(key, 32, 2, session, &p, out);
        printf("\npose ");
        puthex(out, ARSURF_POSE_SIZE);
        f.flags = 0; f.seq = 3; f.ack = 2; f.t = 1.25; f.echo = 0.5;
        memcpy(f.session, session, ARSURF_SESSION_SIZE);
        f.force[0] = 0.0; f.force[1] = 0.0; f.force[2] = 1.5;
        arsurf_encode_force(key, 32, &f, out);
        printf("\nforce ");
        puthex(out, ARSURF_FORCE_SIZE);
        arsurf_encode_release(key, 32, 3, session, 0.75, out);
        printf("\nrelease ");
        puthex(out, ARSURF_RELEASE_SIZE);
        printf("\nself_test %d\n", arsurf_self_test());
        return 0;
    }
    while (fgets(line, sizeof line, stdin)) {
        int n = split(line, tok, 32);
        if (n == 0) continue;
        if (strcmp(mode, "hmac") == 0 && n == 2) {
            size_t kl = unhex(tok[0], key), ml = unhex(tok[1], msg);
            arsurf_hmac_sha256(key, kl, msg, ml, out);
            puthex(out, 32);
        } else if (strcmp(mode, "encode") == 0 && strcmp(tok[0], "pose") == 0 && n == 16) {
            arsurf_pose p;
            int i;
            size_t kl = unhex(tok[1], key);
            unhex(tok[3], sess);
            p.t = f64(tok[4]);
            for (i = 0; i < 3; ++i) {
                p.position[i] = f64(tok[5 + i]);
                p.velocity[i] = f64(tok[8 + i]);
            }
            for (i = 0; i < 4; ++i) p.quaternion[i] = f64(tok[11 + i]);
            p.buttons = (uint32_t)u64(tok[15]);
            arsurf_encode_pose(key, kl, u64(tok[2]), sess, &p, out);
            puthex(out, ARSURF_POSE_SIZE);
        } else if (strcmp(mode, "encode") == 0 && strcmp(tok[0], "release") == 0 && n == 5) {
            size_t kl = unhex(tok[1], key);
            unhex(tok[3], sess);
            arsurf_encode_release(key, kl, u64(tok[2]), sess, f64(tok[4]), out);
            puthex(out, ARSURF_RELEASE_SIZE);
        } else if (strcmp(mode, "encode") == 0 && strcmp(tok[0], "hello") == 0 && n == 4) {
            size_t kl = unhex(tok[1], key);
            arsurf_encode_hello(key, kl, u64(tok[2]), f64(tok[3]), out);
            puthex(out, ARSURF_HELLO_SIZE);
        } else if (strcmp(mode, "encode") == 0 && strcmp(tok[0], "challenge") == 0 && n == 5) {
            size_t kl = unhex(tok[1], key);
            unhex(tok[4], sess);
            arsurf_encode_challenge(key, kl, u64(tok[2]), u64(tok[3]), sess, out);
            puthex(out, ARSURF_CHALLENGE_SIZE);
        } else if (strcmp(mode, "encode") == 0 && strcmp(tok[0], "force") == 0 && n == 11) {
            arsurf_force f;
            int i;
            size_t kl = unhex(tok[1], key);
            f.seq = u64(tok[2]);
            unhex(tok[3], f.session);
            f.ack = u64(tok[4]);
            f.t = f64(tok[5]);
            f.echo = f64(tok[6]);
            for (i = 0; i < 3; ++i) f.force[i] = f64(tok[7 + i]);
            f.flags = (uint16_t)u64(tok[10]);
            arsurf_encode_force(key, kl, &f, out);
            puthex(out, ARSURF_FORCE_SIZE);
        } else if (strcmp(mode, "keyfile") == 0 && n == 1) {
            char err[512];
            size_t kl = 0;
            if (arsurf_read_key_file(tok[0], key, &kl, err, sizeof err) == 0) {
                printf("ok ");
                puthex(key, kl);
            } else {
                printf("error %s", err);
            }
        } else if (strcmp(mode, "check") == 0 && strcmp(tok[0], "client") == 0 && n == 5) {
            size_t kl = unhex(tok[1], key);
            uint64_t k, hellos = u64(tok[3]);
            if (arsurf_client_init(&client, key, kl, u64(tok[2]), f64(tok[4])) != 0) {
                printf("init_failed\n");
                return 1;
            }
            for (k = 0; k < hellos; ++k) arsurf_client_hello(&client, 0.0, out);
            have_client = 1;
            printf("client %llu %llu", (unsigned long long)client.first_seq, (unsigned long long)client.seq);
        } else if (strcmp(mode, "check") == 0 && have_client && strcmp(tok[0], "poses") == 0 && n == 2) {
            uint64_t k, poses = u64(tok[1]), seq = 0;
            arsurf_pose p;
            double zero[3] = {0.0, 0.0, 0.0};
            p = arsurf_pose_at(0.0, zero, NULL);
            for (k = 0; k < poses; ++k) seq = arsurf_client_pose(&client, &p, out);
            printf("%llu", (unsigned long long)seq);
        } else if (strcmp(mode, "check") == 0 && have_client && n == 2) {
            arsurf_force f;
            size_t len = unhex(tok[1], msg);
            arsurf_status s = arsurf_client_check(&client, msg, len, atoi(tok[0]), &f);
            printf("%s", arsurf_status_name(s));
            if (s == ARSURF_OK)
                printf(" %016llx %016llx %016llx", (unsigned long long)arsurf_f64_bits(f.force[0]),
                       (unsigned long long)arsurf_f64_bits(f.force[1]), (unsigned long long)arsurf_f64_bits(f.force[2]));
        } else {
            printf("bad_line");
        }
        printf("\n");
    }
    return 0;
}
