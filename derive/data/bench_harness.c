/* Benchmark harness for the generated kernels (dq-derive bench kernels). Not generated: it is
 * compiled by derive/bench_kernels.py with the flags of the C backend, next to a copy of the
 * robot's generated kernel file, with -DPREFIX=<robot id>.
 *
 * It times, per pose, on n poses read from files: the generated FK and IK, batch and single
 * calls, the FK and IK batches in chunks of CHUNK poses (their output then stays in the cache: the
 * IK batch of all n writes n x 384 bytes, which on a large n is a memory-bandwidth figure), the
 * nearest solution to a seed (the generating joints + 0.01 rad) in one batch and in chunks, and
 * the same FK done by
 * plain 4x4 homogeneous-matrix code (standard DH,
 * T_i = Rz(q_i) Tz(d_i) Tx(a_i) Rx(alpha_i), libm sin/cos, a 4x4 product per joint), which is
 * what a controller would write without a kinematics library. Usage:
 *   harness n repeats dh.bin q.bin poses.bin out_fk_matrix.bin
 * dh.bin: 6 x (d, a, alpha); prints one JSON object. */
#define _DEFAULT_SOURCE   /* clock_gettime, and madvise on Linux */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#if defined(__linux__)
#include <sys/mman.h>
#endif

#define CAT2(a, b) a##b
#define CAT(a, b) CAT2(a, b)
#define FK CAT(PREFIX, _fk)
#define FK_BATCH CAT(PREFIX, _fk_batch)
#define IK CAT(PREFIX, _ik)
#define IK_BATCH CAT(PREFIX, _ik_batch)
#define IK_NEAREST CAT(PREFIX, _ik_nearest_batch)
#define CHUNK 1000

void FK(const double *restrict q, double *restrict out);
void FK_BATCH(size_t n, const double *restrict q, double *restrict out);
int IK(const double *restrict pose, double *restrict sols);
void IK_BATCH(size_t n, const double *restrict poses, double *restrict sols, int *restrict counts);
void IK_NEAREST(size_t n, const double *restrict poses, const double *restrict seeds, double *restrict q,
                double *restrict max_move, double *restrict total_move, int *restrict branch,
                int *restrict singular);

static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

/* Plain 4x4 matrix FK of a 6-joint standard-DH arm: out = 4x4 row-major end pose. */
static void matrix_fk(const double *restrict dh, const double *restrict q, double *restrict out)
{
    double t[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
    for (int i = 0; i < 6; ++i) {
        const double d = dh[3 * i], a = dh[3 * i + 1], al = dh[3 * i + 2];
        const double ct = cos(q[i]), st = sin(q[i]), ca = cos(al), sa = sin(al);
        const double m[16] = {ct, -st * ca, st * sa, a * ct,
                              st, ct * ca, -ct * sa, a * st,
                              0.0, sa, ca, d,
                              0.0, 0.0, 0.0, 1.0};
        double r[16];
        for (int row = 0; row < 4; ++row) {
            for (int col = 0; col < 4; ++col) {
                double s = 0.0;
                for (int k = 0; k < 4; ++k) {
                    s += t[4 * row + k] * m[4 * k + col];
                }
                r[4 * row + col] = s;
            }
        }
        for (int k = 0; k < 16; ++k) {
            t[k] = r[k];
        }
    }
    for (int k = 0; k < 16; ++k) {
        out[k] = t[k];
    }
}

/* malloc, and for 4 MiB or more transparent huge pages where Linux has them: what numpy does
 * for its arrays (alloc.c), so that the harness and kernels() read and write memory alike (with
 * 4 KiB pages the UR5 FK batch of 10^5 poses took about 2 ns per pose more here, in TLB misses). */
static void *alloc(size_t bytes)
{
    void *p = malloc(bytes);
#if defined(__linux__) && defined(MADV_HUGEPAGE)
    if (p != NULL && bytes >= ((size_t)1 << 22)) {
        const uintptr_t a = ((uintptr_t)p + 4095) & ~(uintptr_t)4095;
        (void)madvise((void *)a, bytes - (size_t)(a - (uintptr_t)p), MADV_HUGEPAGE);
    }
#endif
    return p;
}

static double *load(const char *path, size_t count)
{
    double *buf = alloc(count * sizeof(double));
    FILE *f = fopen(path, "rb");
    if (buf == NULL || f == NULL || fread(buf, sizeof(double), count, f) != count) {
        fprintf(stderr, "cannot read %s\n", path);
        exit(1);
    }
    fclose(f);
    return buf;
}

static double best(double a, double b) { return a < b ? a : b; }

/* The best time of `repeats` runs of a statement, run back to back (as derive.bench times a call
 * through kernels() and the peers): the FK batch took 17 ns per UR5 pose when each of its runs
 * followed the IK and nearest runs of the previous round, 12 ns back to back (its input, evicted
 * meanwhile, then stays in the caches). */
#define TIME(t, stmt)                              \
    do {                                           \
        for (int r_ = 0; r_ < repeats; ++r_) {     \
            const double t0_ = now();              \
            stmt;                                  \
            t = best(t, now() - t0_);              \
        }                                          \
    } while (0)

int main(int argc, char **argv)
{
    if (argc != 7) {
        fprintf(stderr, "usage: harness n repeats dh.bin q.bin poses.bin out_fk_matrix.bin\n");
        return 2;
    }
    const size_t n = (size_t)strtoul(argv[1], NULL, 10);
    const int repeats = atoi(argv[2]);
    double *dh = load(argv[3], 18), *q = load(argv[4], n * 6), *poses = load(argv[5], n * 8);
    double *fk = alloc(n * 8 * sizeof(double)), *mat = alloc(n * 16 * sizeof(double));
    double *sols = alloc(n * 48 * sizeof(double)), one[48];
    int *counts = alloc(n * sizeof(int));
    double *seeds = alloc(n * 6 * sizeof(double)), *nq = alloc(n * 6 * sizeof(double));
    double *nmx = alloc(n * sizeof(double)), *ntt = alloc(n * sizeof(double));
    int *nbr = alloc(n * sizeof(int)), *nsg = alloc(n * sizeof(int));
    for (size_t i = 0; i < n * 6; ++i) {
        seeds[i] = q[i] + 0.01;
    }
    double t_fk = 1e9, t_fk1 = 1e9, t_mat = 1e9, t_ik = 1e9, t_ik1 = 1e9, t_ikc = 1e9, t_near = 1e9;
    double t_fkc = 1e9, t_nearc = 1e9;
    volatile double sink = 0.0;
    TIME(t_fk, FK_BATCH(n, q, fk));
    TIME(t_fk1, for (size_t i = 0; i < n; ++i) { FK(q + 6 * i, fk + 8 * i); });
    TIME(t_mat, for (size_t i = 0; i < n; ++i) { matrix_fk(dh, q + 6 * i, mat + 16 * i); });
    TIME(t_ik, IK_BATCH(n, poses, sols, counts));
    TIME(t_ik1, for (size_t i = 0; i < n; ++i) { sink += IK(poses + 8 * i, one); });
    TIME(t_ikc, for (size_t i0 = 0; i0 + CHUNK <= n; i0 += CHUNK) { IK_BATCH(CHUNK, poses + 8 * i0, sols, counts); });
    /* in chunks, the output of each chunk written over the first (in cache), as the IK chunks
       above; before the whole batch, whose answers are counted below */
    TIME(t_fkc, for (size_t i0 = 0; i0 + CHUNK <= n; i0 += CHUNK) { FK_BATCH(CHUNK, q + 6 * i0, fk); });
    TIME(t_nearc, for (size_t i0 = 0; i0 + CHUNK <= n; i0 += CHUNK) {
        IK_NEAREST(CHUNK, poses + 8 * i0, seeds + 6 * i0, nq, nmx, ntt, nbr, nsg);
    });
    TIME(t_near, IK_NEAREST(n, poses, seeds, nq, nmx, ntt, nbr, nsg));
    size_t nfound = 0;
    for (size_t i = 0; i < n; ++i) {
        nfound += nbr[i] >= 0;
    }
    FILE *f = fopen(argv[6], "wb");
    if (f == NULL || fwrite(mat, sizeof(double), n * 16, f) != n * 16) {
        fprintf(stderr, "cannot write %s\n", argv[6]);
        return 1;
    }
    fclose(f);
    printf("{\"fk_batch_ns\": %.3f, \"fk_single_ns\": %.3f, \"matrix_fk_ns\": %.3f, "
           "\"ik_batch_ns\": %.3f, \"ik_single_ns\": %.3f, \"ik_batch_chunked_ns\": %.3f, "
           "\"nearest_batch_ns\": %.3f, \"nearest_found\": %zu, \"fk_batch_chunked_ns\": %.3f, "
           "\"nearest_batch_chunked_ns\": %.3f, \"sink\": %g}\n",
           t_fk / n * 1e9, t_fk1 / n * 1e9, t_mat / n * 1e9, t_ik / n * 1e9, t_ik1 / n * 1e9,
           t_ikc / (double)(n / CHUNK * CHUNK) * 1e9, t_near / n * 1e9, nfound,
           t_fkc / (double)(n / CHUNK * CHUNK) * 1e9, t_nearc / (double)(n / CHUNK * CHUNK) * 1e9, sink);
    free(dh); free(q); free(poses); free(fk); free(mat); free(sols); free(counts);
    free(seeds); free(nq); free(nmx); free(ntt); free(nbr); free(nsg);
    return 0;
}
