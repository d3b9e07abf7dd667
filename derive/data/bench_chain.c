/* The quaternion-versus-matrix claim of seed 000 (dq-derive bench chain). Not generated.
 *
 * For a serial chain of n standard-DH joints, all joint origins O_1 .. O_n are computed
 *   - with unit quaternions, as seed 000 writes it: O_k = Q_1..k (0, r_k) conj(Q_1..k) + O_(k-1),
 *     Q_k = qz(theta_k) qx(alpha_k), r_k = (a_k, 0, 0) rotated by Rz(theta_k) plus (0, 0, d_k)
 *     expressed in frame k-1 (two Hamilton products for the sandwich);
 *   - with 4x4 DH matrices: T_0k = T_0(k-1) A_k, O_k = the last column.
 * "reuse": the partial products Q_1..k, T_0k are carried from joint to joint (O(n));
 * "no reuse": every Q_1..k, T_0k is recomputed from scratch (O(n^2)), as the seed's second graph.
 * Usage: chain nmax batch repeats -> one JSON line per n. */
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#define NMAX 64

static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static void qmul(const double *a, const double *b, double *o)
{
    o[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3];
    o[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2];
    o[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1];
    o[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0];
}

/* joint k: quaternion Q_k and local translation r_k (frame k-1). dh = (d, a, cos, sin of alpha,
 * cos, sin of alpha/2), constant per robot; one sin/cos pair of theta/2 per joint, the full angle
 * by the double-angle formulas (as the generated kernels do). */
static void joint_q(const double *dh, double th, double *q, double *r)
{
    const double d = dh[0], a = dh[1], cx = dh[4], sx = dh[5];
    const double cz = cos(0.5 * th), sz = sin(0.5 * th);
    q[0] = cz * cx;
    q[1] = cz * sx;
    q[2] = sz * sx;
    q[3] = sz * cx;
    r[0] = 0.0;
    r[1] = a * (1.0 - 2.0 * sz * sz);
    r[2] = a * (2.0 * sz * cz);
    r[3] = d;
}

/* joint k: the DH matrix, one sin/cos pair of theta per joint. */
static void joint_m(const double *dh, double th, double *m)
{
    const double d = dh[0], a = dh[1], ca = dh[2], sa = dh[3];
    const double ct = cos(th), st = sin(th);
    const double v[16] = {ct, -st * ca, st * sa, a * ct, st, ct * ca, -ct * sa, a * st,
                          0.0, sa, ca, d, 0.0, 0.0, 0.0, 1.0};
    for (int k = 0; k < 16; ++k) {
        m[k] = v[k];
    }
}

static void mmul(const double *a, const double *b, double *o)
{
    for (int i = 0; i < 4; ++i) {
        for (int j = 0; j < 4; ++j) {
            double s = 0.0;
            for (int k = 0; k < 4; ++k) {
                s += a[4 * i + k] * b[4 * k + j];
            }
            o[4 * i + j] = s;
        }
    }
}

static void sandwich(const double *q, const double *r, double *out)
{
    double t[4], qc[4] = {q[0], -q[1], -q[2], -q[3]}, o[4];
    qmul(q, r, t);
    qmul(t, qc, o);
    out[0] = o[1];
    out[1] = o[2];
    out[2] = o[3];
}

static void origins_quat(int n, const double *dh, const double *th, int reuse, double *org)
{
    double acc[4] = {1, 0, 0, 0}, qs[NMAX][4], rs[NMAX][4], o[3] = {0, 0, 0};
    for (int k = 0; k < n; ++k) {
        joint_q(dh + 6 * k, th[k], qs[k], rs[k]);
    }
    for (int k = 0; k < n; ++k) {
        double v[3];
        if (!reuse) {                     /* Q_1..(k-1) from scratch */
            acc[0] = 1.0; acc[1] = acc[2] = acc[3] = 0.0;
            for (int j = 0; j < k; ++j) {
                double t[4];
                qmul(acc, qs[j], t);
                acc[0] = t[0]; acc[1] = t[1]; acc[2] = t[2]; acc[3] = t[3];
            }
        }
        sandwich(acc, rs[k], v);          /* r_k is expressed in frame k-1 */
        o[0] += v[0]; o[1] += v[1]; o[2] += v[2];
        org[3 * k] = o[0]; org[3 * k + 1] = o[1]; org[3 * k + 2] = o[2];
        if (reuse) {
            double t[4];
            qmul(acc, qs[k], t);
            acc[0] = t[0]; acc[1] = t[1]; acc[2] = t[2]; acc[3] = t[3];
        }
    }
}

static void origins_matrix(int n, const double *dh, const double *th, int reuse, double *org)
{
    double acc[16], ms[NMAX][16];
    for (int k = 0; k < n; ++k) {
        joint_m(dh + 6 * k, th[k], ms[k]);
    }
    for (int k = 0; k < 16; ++k) {
        acc[k] = (k % 5 == 0) ? 1.0 : 0.0;
    }
    for (int k = 0; k < n; ++k) {
        double t[16];
        if (reuse) {
            mmul(acc, ms[k], t);
        } else {                          /* T_0k from scratch */
            double p[16];
            for (int i = 0; i < 16; ++i) {
                p[i] = (i % 5 == 0) ? 1.0 : 0.0;
            }
            for (int j = 0; j <= k; ++j) {
                mmul(p, ms[j], t);
                for (int i = 0; i < 16; ++i) {
                    p[i] = t[i];
                }
            }
        }
        for (int i = 0; i < 16; ++i) {
            acc[i] = t[i];
        }
        org[3 * k] = acc[3]; org[3 * k + 1] = acc[7]; org[3 * k + 2] = acc[11];
    }
}

int main(int argc, char **argv)
{
    if (argc != 4) {
        fprintf(stderr, "usage: chain nmax batch repeats\n");
        return 2;
    }
    const int nmax = atoi(argv[1]), batch = atoi(argv[2]), repeats = atoi(argv[3]);
    double dh[6 * NMAX];
    srand(7);
    for (int k = 0; k < NMAX; ++k) {
        const double al = 6.0 * rand() / RAND_MAX - 3.0;
        dh[6 * k] = 2.0 * rand() / RAND_MAX - 1.0;
        dh[6 * k + 1] = 2.0 * rand() / RAND_MAX - 1.0;
        dh[6 * k + 2] = cos(al);
        dh[6 * k + 3] = sin(al);
        dh[6 * k + 4] = cos(0.5 * al);
        dh[6 * k + 5] = sin(0.5 * al);
    }
    double *th = malloc(sizeof(double) * (size_t)batch * NMAX);
    for (long i = 0; i < (long)batch * NMAX; ++i) {
        th[i] = 6.0 * rand() / RAND_MAX - 3.0;
    }
    double oq[3 * NMAX], om[3 * NMAX];
    for (int n = 1; n <= nmax; ++n) {
        double best[4] = {1e9, 1e9, 1e9, 1e9}, err = 0.0;
        for (int r = 0; r < repeats; ++r) {
            for (int mode = 0; mode < 4; ++mode) {
                const double t0 = now();
                for (int b = 0; b < batch; ++b) {
                    if (mode < 2) {
                        origins_quat(n, dh, th + (long)b * NMAX, mode == 0, oq);
                    } else {
                        origins_matrix(n, dh, th + (long)b * NMAX, mode == 2, om);
                    }
                }
                const double t = (now() - t0) / batch;
                best[mode] = t < best[mode] ? t : best[mode];
            }
        }
        for (int b = 0; b < 10; ++b) {
            origins_quat(n, dh, th + (long)b * NMAX, 1, oq);
            origins_matrix(n, dh, th + (long)b * NMAX, 1, om);
            for (int k = 0; k < 3 * n; ++k) {
                const double e = fabs(oq[k] - om[k]);
                err = e > err ? e : err;
            }
        }
        printf("{\"n\": %d, \"quat_reuse_ns\": %.2f, \"quat_scratch_ns\": %.2f, \"matrix_reuse_ns\": %.2f, "
               "\"matrix_scratch_ns\": %.2f, \"max_diff\": %.3g}\n",
               n, best[0] * 1e9, best[1] * 1e9, best[2] * 1e9, best[3] * 1e9, err);
    }
    free(th);
    return 0;
}
