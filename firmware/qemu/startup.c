/* Minimal start-up for the tests on QEMU's mps2-an386 (Cortex-M4F): a vector table, the FPU
 * switched on before any float instruction runs, then newlib's rdimon _start, which zeroes
 * .bss, runs the static constructors and exits through semihosting with main()'s value. */
#include <stdint.h>

extern void _start(void);
extern void _exit(int status);
extern uint32_t __stack;

void reset_handler(void) {
  /* CPACR: full access to coprocessors 10 and 11 (the FPU). */
  *(volatile uint32_t*)0xE000ED88u |= 0xFu << 20;
  __asm__ volatile("dsb\n\tisb");
  _start();
}

/* A fault ends the run with a distinct status instead of hanging until the timeout. */
void fault_handler(void) { _exit(128); }

__attribute__((section(".vectors"), used)) static void (*const vectors[16])(void) = {
    (void (*)(void))&__stack, reset_handler, fault_handler, fault_handler, fault_handler, fault_handler,
    fault_handler, 0, 0, 0, 0, fault_handler, fault_handler, 0, fault_handler, fault_handler,
};
