/* The simplest fast alternative to sieve on segregation column a (docs/model.md 7.1a):
 * a plain C loop of the same scheme (modified Godunov flux with the uniform c and k of the
 * column, walls at both ends, the same time steps), for the side-by-side rate of
 * core/benches/column_a_vs_c.rs. Built there with `cc -O2` for the portable x86-64 target
 * (SSE2, no FMA contraction), as sieve's own build.
 *
 * usage: column_a N COURANT T_END REPEATS
 * prints: cells steps best_seconds l1_error checksum_bits */
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

/* f(q) = -k q (c - q): the small grains' segregation flux (k > 0: they rise) */
static inline double phys(double q, double c, double k) { return -(k * q * (c - q)); }
static inline double dmax(double a, double b) { return a > b ? a : b; }
static inline double dmin(double a, double b) { return a < b ? a : b; }

int main(int argc, char **argv) {
    if (argc != 5) {
        fprintf(stderr, "usage: column_a N COURANT T_END REPEATS\n");
        return 2;
    }
    const int n = atoi(argv[1]);
    const double courant = atof(argv[2]), t_end = atof(argv[3]);
    const int repeats = atoi(argv[4]);
    const double c = 0.64, s = 1.0, h = 1.0 / n, k = s / c, half = 0.5 * c;
    double *q = malloc(n * sizeof *q), *f = malloc((n - 1) * sizeof *f);
    const double dt_max = courant / (s / h); /* sieve: Courant / rate, rate = |S|/h */
    long steps = 0;
    double best = 1e300;
    for (int r = 0; r < repeats; r++) {
        for (int i = 0; i < n; i++) q[i] = c * 0.5;
        double t = 0.0;
        steps = 0;
        const double t0 = now();
        while (t < t_end) {
            double dt = dt_max;
            if (t + dt > t_end) dt = t_end - t;
            const double lambda = dt / h;
            for (int j = 0; j < n - 1; j++) {
                const double a = phys(dmax(q[j], half), c, k);
                const double b = phys(dmin(q[j + 1], half), c, k);
                f[j] = dmax(a, b) * lambda;
            }
            q[0] -= f[0];
            for (int j = 1; j < n - 1; j++) q[j] += f[j - 1] - f[j];
            q[n - 1] += f[n - 2];
            t += dt;
            steps++;
        }
        const double el = now() - t0;
        if (el < best) best = el;
    }
    /* L1 error of phihat against the exact cell averages (two shocks from the walls) */
    const double m = 0.5, lo = fmin(s * m * t_end, m), hi = fmax(1.0 - s * (1.0 - m) * t_end, m);
    double l1 = 0.0;
    uint64_t sum = 0;
    for (int i = 0; i < n; i++) {
        const double z0 = i * h, z1 = (i + 1) * h;
        const double ov_lo = fmax(fmin(lo, z1) - z0, 0.0);
        const double ov_mid = fmax(fmin(hi, z1) - fmax(lo, z0), 0.0);
        const double exact = (ov_lo + m * ov_mid) / h;
        l1 += fabs(q[i] / c - exact) * h;
        uint64_t bits;
        memcpy(&bits, &q[i], 8);
        sum = sum * 1099511628211ull + bits;
    }
    printf("%d %ld %.9e %.9e %llu\n", n, steps, best, l1, (unsigned long long)sum);
    free(q);
    free(f);
    return 0;
}
