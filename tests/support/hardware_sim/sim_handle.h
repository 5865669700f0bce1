/* A simulated haptic handle for the vendor-library simulators (fdsdk_sim.c, hd_sim.c).
 *
 * Per axis a mass m with damping b, held by a hand: a spring k_h and damper b_h to a set point
 * p(t) = p0 + a sin(2 pi f t), driven by the force the library applies (saturated at fmax_hw):
 *
 *     m x'' = F - b x' + k_h (p - x) + b_h (p' - x')
 *
 * integrated with semi-implicit Euler in steps of 50 us up to the requested time. Units are SI
 * (m, m/s, N, s) in the vendor's frame; each simulator converts to its library's units. */
#ifndef SIM_HANDLE_H
#define SIM_HANDLE_H
#include <math.h>
#include <pthread.h>
#include <time.h>

typedef struct {
    double m, b, kh, bh;        /* kg, N s/m, N/m, N s/m (same on the three axes) */
    double p0[3], amp[3], freq; /* hand set point: m, m, Hz */
    double x[3], v[3];          /* state: m, m/s */
    double f[3];                /* force applied to the handle now: N */
    double t;                   /* simulated time: s */
    double fmax_hw;             /* motor saturation: N */
} sim_handle;

static double sim_clock(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

static void sim_handle_init(sim_handle *h, double fmax_hw) {
    h->m = 0.2; h->b = 2.0; h->kh = 200.0; h->bh = 5.0; h->freq = 0.0;
    for (int a = 0; a < 3; a++) { h->p0[a] = 0; h->amp[a] = 0; h->x[a] = 0; h->v[a] = 0; h->f[a] = 0; }
    h->t = 0; h->fmax_hw = fmax_hw;
}

static void sim_hand(const sim_handle *h, double t, double p[3], double dp[3]) {
    double w = 2.0 * M_PI * h->freq;
    for (int a = 0; a < 3; a++) {
        p[a] = h->p0[a] + h->amp[a] * sin(w * t);
        dp[a] = h->amp[a] * w * cos(w * t);
    }
}

/* advance to time t (never more than 0.2 s at once: a stalled caller is not a physics problem) */
static void sim_handle_advance(sim_handle *h, double t) {
    const double step = 5e-5;
    if (t - h->t > 0.2) h->t = t - 0.2;
    while (h->t + step <= t) {
        double p[3], dp[3];
        sim_hand(h, h->t, p, dp);
        for (int a = 0; a < 3; a++) {
            double acc = (h->f[a] - h->b * h->v[a] + h->kh * (p[a] - h->x[a]) + h->bh * (dp[a] - h->v[a])) / h->m;
            h->v[a] += step * acc;
            h->x[a] += step * h->v[a];
        }
        h->t += step;
    }
}

/* set the applied force, saturated in norm at fmax_hw; returns 1 if it was saturated */
static int sim_handle_force(sim_handle *h, const double f[3]) {
    double n = sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
    double s = (n > h->fmax_hw) ? h->fmax_hw / n : 1.0;
    for (int a = 0; a < 3; a++) h->f[a] = f[a] * s;
    return n > h->fmax_hw;
}
#endif
