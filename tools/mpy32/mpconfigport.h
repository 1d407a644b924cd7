// ropemon mpy32: a minimal 32-bit MicroPython for running the firmware tests with the native
// emitter (x86 with gcc -m32, or ARM Thumb-2 under qemu-user). Built by tools/mpy32/build.sh.
#include <stdint.h>
#include <alloca.h>

#define MICROPY_CONFIG_ROM_LEVEL (MICROPY_CONFIG_ROM_LEVEL_EXTRA_FEATURES)

// The native emitter of the target: viper and @native run as machine code.
#if defined(__i386__)
#define MICROPY_EMIT_X86            (1)
#elif defined(__thumb2__)
#define MICROPY_EMIT_THUMB          (1)
#define MICROPY_EMIT_INLINE_THUMB   (1)
#define MICROPY_MAKE_POINTER_CALLABLE(p) ((void *)((uintptr_t)(p) | 1))
#else
#error "mpy32 builds for i386 (-m32) or Thumb-2 (-mthumb) only"
#endif
#if UINTPTR_MAX != 0xffffffffu
#error "mpy32 is a 32-bit build"
#endif

#define MICROPY_ENABLE_GC           (1)
#define MICROPY_ENABLE_FINALISER    (1)
#define MICROPY_ENABLE_PYSTACK      (0)
#define MICROPY_STACK_CHECK         (1)
#define MICROPY_MEM_STATS           (1)
#define MICROPY_MALLOC_USES_ALLOCATED_SIZE (1)
#define MICROPY_HELPER_REPL         (0)
#define MICROPY_ENABLE_COMPILER     (1)
#define MICROPY_PERSISTENT_CODE_LOAD (1)
#define MICROPY_READER_POSIX        (1)
#define MICROPY_LONGINT_IMPL        (MICROPY_LONGINT_IMPL_MPZ)
#define MICROPY_FLOAT_IMPL          (MICROPY_FLOAT_IMPL_DOUBLE)
#define MICROPY_ERROR_REPORTING     (MICROPY_ERROR_REPORTING_DETAILED)
#define MICROPY_WARNINGS            (1)
#define MICROPY_ENABLE_SOURCE_LINE  (1)
#define MICROPY_MODULE_FROZEN_MPY   (0)
#define MICROPY_MODULE_FROZEN_STR   (0)
#define MICROPY_USE_INTERNAL_PRINTF (0)
#define MICROPY_PY_SYS_PATH         (1)
#define MICROPY_PY_SYS_ARGV         (1)
#define MICROPY_PY_SYS_EXIT         (1)
#define MICROPY_PY_SYS_STDFILES     (1)
#define MICROPY_PY_SYS_MAXSIZE      (1)
#define MICROPY_PY_SYS_PLATFORM     "linux"
#define MICROPY_PY_IO               (1)
#define MICROPY_PY_ARRAY            (1)
#define MICROPY_PY_STRUCT           (1)
#define MICROPY_PY_MATH             (1)
#define MICROPY_PY_GC               (1)
#define MICROPY_PY_MICROPYTHON_MEM_INFO (1)
#define MICROPY_PY_MICROPYTHON_HEAP_LOCKED (1)
#define MICROPY_PY_BUILTINS_HELP    (0)
#define MICROPY_PY_BUILTINS_INPUT   (0)
#define MICROPY_PY_THREAD           (0)
// Modules of extmod/ (absent from the source used) are either written here in C
// (os, time, hashlib, binascii: modmpy32.c) or in Python (json, random: lib/).
#define MICROPY_PY_OS               (0)
#define MICROPY_PY_TIME             (0)
#define MICROPY_PY_JSON             (0)
#define MICROPY_PY_RE               (0)
#define MICROPY_PY_RANDOM           (0)
#define MICROPY_PY_HASHLIB          (0)
#define MICROPY_PY_BINASCII         (0)
#define MICROPY_PY_SELECT           (0)
#define MICROPY_PY_HEAPQ            (0)
#define MICROPY_PY_DEFLATE          (0)
#define MICROPY_PY_FRAMEBUF         (0)
#define MICROPY_PY_PLATFORM         (0)
#define MICROPY_PY_ASYNCIO          (0)
#define MICROPY_PY_UCTYPES          (0)
#define MICROPY_PY_MACHINE          (0)
#define MICROPY_VFS                 (0)
#define MICROPY_PY_OS_DUPTERM       (0)

#define MICROPY_ALLOC_PATH_MAX      (256)

typedef intptr_t mp_int_t;
typedef uintptr_t mp_uint_t;
typedef long mp_off_t;

#define MICROPY_HW_BOARD_NAME "mpy32"
#if defined(__i386__)
#define MICROPY_HW_MCU_NAME "i386"
#else
#define MICROPY_HW_MCU_NAME "armv7-thumb2"
#endif

// Native code is written into the (executable) GC heap; make it visible to the CPU.
void *mpy32_commit_exec(void *buf, size_t len, void *opt);
#define MP_PLAT_COMMIT_EXEC(buf, len, opt) mpy32_commit_exec(buf, len, opt)

#define MP_STATE_PORT MP_STATE_VM
