@ Hand-written Thumb-2 loops whose Cortex-M4 cycle counts follow from the TRM's timing table
@ (tests/test_cycles.py writes each count out by hand). Each loop is the step of a tiny
@ "filter" <name>_step(state *s /* r0 */, const input *in /* r1 */, float dt /* s0 */) that
@ returns 0, so the harness builds and counts it like any filter; <name>_init does nothing.

    .syntax unified
    .thumb
    .text

    .macro FUNC name
    .global \name
    .type \name, %function
    .thumb_func
    .align 2
\name:
    .endm

    .macro INIT name
    FUNC \name\()_init
    bx lr
    .endm

@ 100 x (vdiv.f32 + vsqrt.f32), counted down
    INIT cyc_div
    FUNC cyc_div_step
    movs r3, #100
1:  vdiv.f32 s1, s2, s3
    vsqrt.f32 s4, s5
    subs r3, r3, #1
    bne 1b
    movs r0, #0
    bx lr

@ 100 x (vmul.f32 + vadd.f32)
    INIT cyc_muladd
    FUNC cyc_muladd_step
    movs r3, #100
1:  vmul.f32 s1, s2, s3
    vadd.f32 s4, s4, s1
    subs r3, r3, #1
    bne 1b
    movs r0, #0
    bx lr

@ 64 x (two loads, two stores): swaps two words of the state
    INIT cyc_ldst
    FUNC cyc_ldst_step
    movs r3, #64
    mov r2, r0
1:  ldr r12, [r2]
    ldr r1, [r2, #4]
    str r12, [r2, #4]
    str r1, [r2]
    subs r3, r3, #1
    bne 1b
    movs r0, #0
    bx lr

@ 32 x (vldr, vldr, vmla.f32, vstr) between a vpush and a vpop of four registers
    INIT cyc_fpmem
    FUNC cyc_fpmem_step
    vpush {s16-s19}
    movs r3, #32
1:  vldr s16, [r0]
    vldr s17, [r0, #4]
    vmla.f32 s18, s16, s17
    vstr s18, [r0, #8]
    subs r3, r3, #1
    bne 1b
    vpop {s16-s19}
    movs r0, #0
    bx lr

@ 50 iterations, r4 = 50..1: a forward branch taken when r4 is even, a call to a leaf when odd
    INIT cyc_branch
    FUNC cyc_branch_step
    push {r4, lr}
    movs r4, #50
1:  tst r4, #1
    beq 2f
    bl cyc_leaf
2:  subs r4, r4, #1
    bne 1b
    movs r0, #0
    pop {r4, pc}

    FUNC cyc_leaf
    adds r2, r2, #1
    bx lr
