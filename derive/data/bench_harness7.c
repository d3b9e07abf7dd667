/* Benchmark harness for the generated IK kernels of a 7-joint arm with one free parameter
 * (dq-derive bench kernels on panda, fr3, iiwa7, iiwa14). Not generated: it is compiled by
 * derive/bench/redundant.py with the flags of the C backend, next to a copy of the robot's
 * generated kernel file, with -DPREFIX=<robot id>.
 *
 * It times, per pose (best of repeats): the IK batch with one free value per pose in chunks of
 * CHUNK poses (the output stays in the cache) and in one call of all n, the single-pose IK in a
 * loop, and a sweep: ns poses times m free values each, m rows per pose given to the batch in
 * chunks of SWEEP_ROWS rows (the poses are repeated m times in the input, as the batch takes one
 * pose per row). Usage:
 *   harness7 n repeats poses.bin fv.bin ns m sweep_poses.bin sweep_fv.bin
 * poses.bin: n x 8 unit dual quaternions; fv.bin: n free values; sweep_poses.bin: ns x 8;
 * sweep_fv.bin: ns x m free values. Prints one JSON object (seconds per pose, and the summed solution counts). */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define CAT2(a, b) a##b
#define CAT(a, b) CAT2(a, b)
#define IK CAT(PREFIX, _ik)
#define IK_BATCH CAT(PREFIX, _ik_batch)
#define CHUNK 1000
#define SWEEP_ROWS 1024

int IK(const double *restrict pose, double fv, double *restrict sols);
void IK_BATCH(size_t n, const double *restrict poses, const double *restrict fv, double *restrict sols,
              int *restrict counts);

static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static double *load(const char *path, size_t count)
{
    double *buf = malloc(count * sizeof(double));
    FILE *f = fopen(path, "rb");
    if (buf == NULL || f == NULL || fread(buf, sizeof(double), count, f) != count) {
        fprintf(stderr, "cannot read %s\n", path);
        exit(1);
    }
    fclose(f);
    return buf;
}

static double best(double a, double b) { return a < b ? a : b; }

int main(int argc, char **argv)
{
    if (argc != 9) {
        fprintf(stderr, "usage: harness7 n repeats poses.bin fv.bin ns m sweep_poses.bin sweep_fv.bin\n");
        return 2;
    }
    const size_t n = (size_t)strtoul(argv[1], NULL, 10);
    const int repeats = atoi(argv[2]);
    const size_t ns = (size_t)strtoul(argv[5], NULL, 10), m = (size_t)strtoul(argv[6], NULL, 10);
    double *poses = load(argv[3], n * 8), *fv = load(argv[4], n);
    double *sp = load(argv[7], ns * 8), *sfv = load(argv[8], ns * m);
    double *sols = malloc(n * 56 * sizeof(double)), one[56];
    int *counts = malloc(n * sizeof(int));
    const size_t rows = ns * m;
    double *spose = malloc(rows * 8 * sizeof(double)), *ssols = malloc(SWEEP_ROWS * 56 * sizeof(double));
    int *scounts = malloc(SWEEP_ROWS * sizeof(int));
    if (sols == NULL || counts == NULL || spose == NULL || ssols == NULL || scounts == NULL) {
        fprintf(stderr, "out of memory\n");
        return 1;
    }
    for (size_t i = 0; i < ns; ++i) {
        for (size_t j = 0; j < m; ++j) {
            memcpy(spose + 8 * (i * m + j), sp + 8 * i, 8 * sizeof(double));
        }
    }
    double t_chunk = 1e9, t_all = 1e9, t_one = 1e9, t_sweep = 1e9;
    long c_all = 0, c_one = 0, c_sweep = 0;
    for (int r = 0; r < repeats; ++r) {
        c_all = c_one = c_sweep = 0;
        double t0 = now();
        for (size_t i0 = 0; i0 < n; i0 += CHUNK) {
            const size_t k = n - i0 < CHUNK ? n - i0 : CHUNK;
            IK_BATCH(k, poses + 8 * i0, fv + i0, sols, counts);
        }
        double t1 = now();
        t_chunk = best(t_chunk, t1 - t0);
        t0 = now();
        IK_BATCH(n, poses, fv, sols, counts);
        t1 = now();
        t_all = best(t_all, t1 - t0);
        for (size_t i = 0; i < n; ++i) {
            c_all += counts[i];
        }
        t0 = now();
        for (size_t i = 0; i < n; ++i) {
            c_one += IK(poses + 8 * i, fv[i], one);
        }
        t1 = now();
        t_one = best(t_one, t1 - t0);
        t0 = now();
        for (size_t i0 = 0; i0 < rows; i0 += SWEEP_ROWS) {
            const size_t k = rows - i0 < SWEEP_ROWS ? rows - i0 : SWEEP_ROWS;
            IK_BATCH(k, spose + 8 * i0, sfv + i0, ssols, scounts);
            for (size_t i = 0; i < k; ++i) {
                c_sweep += scounts[i];
            }
        }
        t1 = now();
        t_sweep = best(t_sweep, t1 - t0);
    }
    printf("{\"ik_batch_chunked_s\": %.9e, \"ik_batch_s\": %.9e, \"ik_single_s\": %.9e, "
           "\"sweep_s\": %.9e, \"count_batch\": %ld, \"count_single\": %ld, \"count_sweep\": %ld, "
           "\"chunk\": %d}\n",
           t_chunk / (double)n, t_all / (double)n, t_one / (double)n, t_sweep / (double)ns, c_all, c_one,
           c_sweep, CHUNK);
    free(poses); free(fv); free(sp); free(sfv); free(sols); free(counts); free(spose); free(ssols); free(scounts);
    return 0;
}
