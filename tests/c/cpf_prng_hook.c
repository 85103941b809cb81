/*
 * cpf_prng_hook.c - test hook for the CPF's generated PRNG (tests/test_cpf.py).
 *
 * Includes a generated cpf.c so that its static PRNG functions are reachable, and exports
 * them for ctypes. Compile: cc -DCPF_SOURCE='"cpf.c"' -I<generated dir> -shared ...
 * CPF_REAL must match the generated precision.
 */
#include CPF_SOURCE

void cpf_hook_u32(uint32_t state[2], uint32_t n, uint32_t *out)
{
    for (uint32_t k = 0u; k < n; k++) {
        out[k] = cpf_rng_next(state);
    }
}

void cpf_hook_uniform(uint32_t state[2], uint32_t n, CPF_REAL *out)
{
    for (uint32_t k = 0u; k < n; k++) {
        out[k] = cpf_rng_uniform(state);
    }
}

void cpf_hook_gauss4(uint32_t state[2], uint32_t n, CPF_REAL *out)
{
    for (uint32_t k = 0u; k < n; k++) {
        cpf_rng_gauss4(state, &out[4u * k]);
    }
}

void cpf_hook_exp_nonpos(const CPF_REAL *x, uint32_t n, CPF_REAL *out)
{
    for (uint32_t k = 0u; k < n; k++) {
        out[k] = cpf_exp_nonpos(x[k]);
    }
}

void cpf_hook_exp2_64(const CPF_REAL *t, uint32_t n, CPF_REAL *out)
{
    for (uint32_t k = 0u; k < n; k++) {
        out[k] = cpf_exp2_64(t[k]);
    }
}
