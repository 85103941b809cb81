/* Links newlib's float libm functions into an image so that firmware_sim/target.py can call
 * them one by one in the emulator and compare them with the host's glibc (libm_survey). */
#include <math.h>

typedef float (*f1_t)(float);
typedef float (*f2_t)(float, float);

volatile f1_t g_probe_f1[] = {sinf, cosf, tanf, asinf, acosf, atanf, expf, logf};
volatile f2_t g_probe_f2[] = {atan2f, powf};

int main(void)
{
    return (g_probe_f1[0] != 0 && g_probe_f2[0] != 0) ? 0 : 1;
}
