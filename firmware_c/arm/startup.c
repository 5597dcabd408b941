/* Cortex-M4F start for QEMU's mps2-an386 board: the vector table, the FPU switched on before any
 * float instruction, then newlib's crt0 (_start: .bss, semihosted argv, main, exit). */
extern void _start(void);
extern unsigned long __stack_top;

void reset_handler(void);
void fault_handler(void);

__attribute__((section(".vectors"), used)) void (*const vectors[16])(void) = {
    (void (*)(void))(&__stack_top), reset_handler, fault_handler, fault_handler, fault_handler, fault_handler,
    fault_handler, 0, 0, 0, 0, fault_handler, fault_handler, 0, fault_handler, fault_handler,
};

void reset_handler(void)
{
    *(volatile unsigned long *)0xE000ED88u |= 0xFu << 20; /* CPACR: CP10, CP11 full access */
    __asm volatile("dsb\n isb");
    _start();
    for (;;) {
    }
}

void fault_handler(void)
{
    /* semihosting SYS_EXIT with ADP_Stopped_RunTimeError: QEMU stops with a non-zero status */
    __asm volatile("mov r0, #0x18\n ldr r1, =0x20023\n bkpt 0xab");
    for (;;) {
    }
}
