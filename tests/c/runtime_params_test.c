/* Runtime parameters of a build generated with --prefix att --runtime kp,ki (QCF's gains):
 * set_params refuses an out-of-range, NaN or infinite value as a whole and leaves the state
 * byte-for-byte untouched; a valid set is applied. Exit 0 when every check holds. */
#include "att.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

static int failures = 0;

static void check(int cond, const char *what)
{
    if (!cond) {
        printf("FAIL: %s\n", what);
        failures++;
    }
}

static void refused(att_state *s, float kp, float ki, uint32_t code, const char *what)
{
    att_state before;
    att_params p;
    memcpy(&before, s, sizeof before);
    att_params_default(&p);
    p.kp = kp;
    p.ki = ki;
    check(att_set_params(s, &p) == code, what);
    check(memcmp(&before, s, sizeof before) == 0, what);
}

int main(void)
{
    att_state s;
    att_input in;
    att_params p;
    memset(&in, 0, sizeof in);
    att_init(&s);
    att_params_default(&p);
    check(p.kp == 0.25f && p.ki == 0.002f, "defaults are the declared ones");
    check(s.params.kp == p.kp && s.params.ki == p.ki, "init sets the defaults");
    in.gyro[0] = 0.1f; in.gyro[1] = -0.05f; in.gyro[2] = 0.2f;
    in.accel[2] = -9.81f; in.accel[0] = 0.3f;
    in.mag[0] = 0.2f; in.mag[2] = 0.4f;
    in.valid = ATT_VALID_GYRO | ATT_VALID_ACCEL | ATT_VALID_MAG;
    for (int k = 0; k < 200; k++) {
        (void)att_step(&s, &in, 0.01f);
    }
    refused(&s, -1.0f, 0.002f, ATT_PARAM_KP, "kp < 0 refused");
    refused(&s, 0.0f, 0.002f, ATT_PARAM_KP, "kp = 0 refused (range open at 0)");
    refused(&s, 100.5f, 0.002f, ATT_PARAM_KP, "kp above 100 refused");
    refused(&s, NAN, 0.002f, ATT_PARAM_KP, "kp NaN refused");
    refused(&s, INFINITY, 0.002f, ATT_PARAM_KP, "kp +Inf refused");
    refused(&s, 1.0f, 10.5f, ATT_PARAM_KI, "ki above 10 refused, valid kp not applied");
    refused(&s, 1.0f, -INFINITY, ATT_PARAM_KI, "ki -Inf refused");
    refused(&s, 1.0f, NAN, ATT_PARAM_KI, "ki NaN refused");
    p.kp = 100.0f;
    p.ki = 10.0f;
    check(att_set_params(&s, &p) == ATT_PARAMS_OK, "upper bounds are allowed");
    p.kp = 1.5f;
    p.ki = 0.01f;
    check(att_set_params(&s, &p) == ATT_PARAMS_OK, "valid set applied");
    check(s.params.kp == 1.5f && s.params.ki == 0.01f, "valid set stored");
    float q0 = s.q[0];
    (void)att_step(&s, &in, 0.01f);
    check(isfinite(s.q[0]) && q0 == q0, "steps after a set");
    printf(failures ? "%d failure(s)\n" : "ok\n", failures);
    return failures ? 1 : 0;
}
