/*
 * main_log.c - firmware-like main loop over a recorded sensor log, for one generated filter.
 *
 * Build with the generated source (ahrsgen does it: src/ahrsgen/bench/harness.py build_log_runner):
 *   cc -std=c99 ... -DAHRS_PREFIX=qcf -DAHRS_HEADER='"qcf.h"' -DAHRS_REAL=float \
 *      -I<generated dir> main_log.c qcf.c -lm -o qcf_log
 * Run:
 *   qcf_log LOG.csv [OUT.csv]
 *
 * The log (written by `ahrsgen run --export-log` / ahrsgen.bench.write_harness_log):
 *   # ahrsgen harness log v1
 *   # dt0 <seconds>                     (dt of the first step)
 *   t,gx,gy,gz,ax,ay,az,mx,my,mz,vn,ve,vd
 *   one row per IMU interrupt; a sensor group whose three fields are empty delivered no
 *   sample at that instant.
 * Like a flight controller's loop, each row fills the input struct, sets a valid bit only
 * for the sensors that delivered a sample, takes dt from the timestamps (t_k - t_{k-1}, so
 * jitter and dropouts reach the filter as they happened), calls <prefix>_step and reads the
 * attitude. Output CSV: t,qw,qx,qy,qz,roll,pitch,yaw,status (radians). A summary (steps,
 * refused steps, ns per step measured around the step calls only) goes to stderr.
 */
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include AHRS_HEADER

#define AHRS_CAT_(a, b) a##_##b
#define AHRS_CAT(a, b) AHRS_CAT_(a, b)
#define PFX(name) AHRS_CAT(AHRS_PREFIX, name)

typedef AHRS_REAL real_t;

#define N_FIELDS 13
#define LINE_MAX_LEN 4096

/* Split a CSV line into N_FIELDS numbers; present[i] = 0 for an empty field. */
static int parse_row(char *line, double v[N_FIELDS], int present[N_FIELDS])
{
    char *p = line;
    int i;
    for (i = 0; i < N_FIELDS; i++) {
        char *end = p;
        while (*end != ',' && *end != '\0' && *end != '\n' && *end != '\r') end++;
        if (end == p) {
            present[i] = 0;
            v[i] = 0.0;
        } else {
            char *num_end;
            v[i] = strtod(p, &num_end);
            if (num_end == p) return -1;
            present[i] = 1;
        }
        if (i < N_FIELDS - 1) {
            if (*end != ',') return -1;
            p = end + 1;
        }
    }
    return 0;
}

static int group_present(const int present[N_FIELDS], int first)
{
    return present[first] && present[first + 1] && present[first + 2];
}

static void set3(real_t dst[3], const double v[N_FIELDS], int first)
{
    dst[0] = (real_t)v[first];
    dst[1] = (real_t)v[first + 1];
    dst[2] = (real_t)v[first + 2];
}

static double now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e9 + (double)ts.tv_nsec;
}

int main(int argc, char **argv)
{
    FILE *in, *out;
    char line[LINE_MAX_LEN];
    double v[N_FIELDS], t_prev = 0.0, dt0 = -1.0, step_ns = 0.0;
    int present[N_FIELDS];
    unsigned long n = 0ul, refused = 0ul, lineno = 0ul;
    int have_header = 0;
    const int prec = (sizeof(real_t) == sizeof(double)) ? 17 : 9;   /* round-trip exact */
    PFX(state) s;
    PFX(input) inp;

    if (argc < 2 || argc > 3) {
        fprintf(stderr, "usage: %s LOG.csv [OUT.csv]\n", argv[0]);
        return 2;
    }
    in = fopen(argv[1], "r");
    if (in == NULL) {
        fprintf(stderr, "%s: cannot open %s\n", argv[0], argv[1]);
        return 2;
    }
    out = (argc == 3) ? fopen(argv[2], "w") : stdout;
    if (out == NULL) {
        fprintf(stderr, "%s: cannot write %s\n", argv[0], argv[2]);
        fclose(in);
        return 2;
    }
    fprintf(out, "t,qw,qx,qy,qz,roll,pitch,yaw,status\n");
    PFX(init)(&s);
    memset(&inp, 0, sizeof inp);

    while (fgets(line, sizeof line, in) != NULL) {
        real_t rpy[3], dt;
        uint32_t status;
        double t0;
        lineno++;
        if (line[0] == '#') {
            if (strncmp(line, "# dt0 ", 6) == 0) dt0 = strtod(line + 6, NULL);
            continue;
        }
        if (!have_header) {           /* column names */
            have_header = 1;
            continue;
        }
        if (parse_row(line, v, present) != 0 || !present[0]) {
            fprintf(stderr, "%s: %s line %lu: malformed row\n", argv[0], argv[1], lineno);
            return 2;
        }
        /* what arrived since the last interrupt: valid bits only for delivered samples */
        inp.valid = 0u;
        if (group_present(present, 1)) { set3(inp.gyro, v, 1); inp.valid |= 1u; }
        if (group_present(present, 4)) { set3(inp.accel, v, 4); inp.valid |= 2u; }
        if (group_present(present, 7)) { set3(inp.mag, v, 7); inp.valid |= 4u; }
        if (group_present(present, 10)) { set3(inp.gps_vel_ned, v, 10); inp.valid |= 8u; }
        dt = (real_t)((n == 0ul) ? dt0 : v[0] - t_prev);
        t_prev = v[0];

        t0 = now_ns();
        status = (uint32_t)PFX(step)(&s, &inp, dt);
        PFX(euler)(&s, rpy);
        step_ns += now_ns() - t0;

        if ((status & 0x20Fu) != 0u) refused++;   /* DT_INVALID|DT_TOO_LARGE|GYRO_MISSING|GYRO_NONFINITE|GYRO_RANGE */
        fprintf(out, "%.17g,%.*g,%.*g,%.*g,%.*g,%.*g,%.*g,%.*g,%lu\n", v[0],
                prec, (double)s.q[0], prec, (double)s.q[1], prec, (double)s.q[2], prec, (double)s.q[3],
                prec, (double)rpy[0], prec, (double)rpy[1], prec, (double)rpy[2], (unsigned long)status);
        n++;
    }
    fclose(in);
    if (out != stdout) fclose(out);
    fprintf(stderr, "%lu steps, %lu refused, %.1f ns per step (step + euler, this host)\n",
            n, refused, n ? step_ns / (double)n : 0.0);
    return 0;
}
