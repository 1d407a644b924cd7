// ropemon mpy32: a REPL-less runner of the MicroPython core (py/) for 32-bit targets.
//
//   micropython [-X heapsize=N[K|M]] (-c CODE | FILE.py) [ARGS...]
//
// sys.path: "" (or the script's folder), then each entry of $MICROPYPATH, then this build's
// lib/ (json.py, random.py: extmod/ is not in the source used). Exit code: 0, the
// SystemExit value, or 1 on an uncaught exception (printed to stderr).
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <sys/mman.h>
#include <sys/stat.h>

#include "py/builtin.h"
#include "py/compile.h"
#include "py/gc.h"
#include "py/mperrno.h"
#include "py/mphal.h"
#include "py/runtime.h"
#include "py/cstack.h"
#include "shared/runtime/gchelper.h"

#ifndef MPY32_LIB
#define MPY32_LIB ""
#endif

static char *stack_top;

static void stderr_strn(void *env, const char *str, size_t len) {
    (void)env;
    ssize_t r = write(2, str, len);
    (void)r;
}
static const mp_print_t stderr_print = {NULL, stderr_strn};

void *mpy32_commit_exec(void *buf, size_t len, void *opt) {
    (void)opt;
    __builtin___clear_cache((char *)buf, (char *)buf + len);
    return buf;
}

void gc_collect(void) {
    gc_collect_start();
    gc_helper_collect_regs_and_stack();
    gc_collect_end();
}

mp_import_stat_t mp_import_stat(const char *path) {
    struct stat st;
    if (stat(path, &st) == 0) {
        if (S_ISDIR(st.st_mode)) {
            return MP_IMPORT_STAT_DIR;
        } else if (S_ISREG(st.st_mode)) {
            return MP_IMPORT_STAT_FILE;
        }
    }
    return MP_IMPORT_STAT_NO_EXIST;
}

void nlr_jump_fail(void *val) {
    (void)val;
    fprintf(stderr, "FATAL: uncaught NLR %p\n", val);
    exit(1);
}

void MP_NORETURN __fatal_error(const char *msg) {
    fprintf(stderr, "FATAL: %s\n", msg);
    exit(1);
}

#ifndef NDEBUG
void MP_WEAK __assert_func(const char *file, int line, const char *func, const char *expr) {
    fprintf(stderr, "Assertion '%s' failed, at file %s:%d\n", expr, file, line);
    __fatal_error("Assertion failed");
}
#endif

static int run(mp_lexer_t *(*make)(const char *), const char *src, bool is_file) {
    nlr_buf_t nlr;
    if (nlr_push(&nlr) == 0) {
        mp_lexer_t *lex = make(src);
        qstr source_name = lex->source_name;
        if (is_file) {
            mp_store_global(MP_QSTR___file__, MP_OBJ_NEW_QSTR(source_name));
        }
        mp_parse_tree_t tree = mp_parse(lex, MP_PARSE_FILE_INPUT);
        mp_obj_t fun = mp_compile(&tree, source_name, false);
        mp_call_function_0(fun);
        mp_handle_pending(MP_HANDLE_PENDING_CALLBACKS_AND_EXCEPTIONS);
        nlr_pop();
        return 0;
    }
    mp_obj_base_t *exc = nlr.ret_val;
    if (mp_obj_is_subclass_fast(MP_OBJ_FROM_PTR(exc->type), MP_OBJ_FROM_PTR(&mp_type_SystemExit))) {
        mp_obj_t v = mp_obj_exception_get_value(MP_OBJ_FROM_PTR(exc));
        mp_int_t val = 0;
        if (v != mp_const_none && !mp_obj_get_int_maybe(v, &val)) {
            val = 1;
        }
        return val & 255;
    }
    mp_obj_print_exception(&stderr_print, MP_OBJ_FROM_PTR(exc));
    return 1;
}

static mp_lexer_t *lex_str(const char *s) {
    return mp_lexer_new_from_str_len(MP_QSTR__lt_stdin_gt_, s, strlen(s), false);
}

static mp_lexer_t *lex_file(const char *path) {
    return mp_lexer_new_from_file(qstr_from_str(path));
}

static void path_append(const char *p, size_t n) {
    mp_obj_list_append(mp_sys_path, mp_obj_new_str_via_qstr(p, n));
}

int main(int argc, char **argv) {
    int dummy;
    stack_top = (char *)&dummy;
    mp_cstack_init_with_top(stack_top, 1 << 20);

    long heap_size = 4 * 1024 * 1024;
    int a = 1;
    while (a < argc && strcmp(argv[a], "-X") == 0 && a + 1 < argc) {
        const char *opt = argv[a + 1];
        if (strncmp(opt, "heapsize=", 9) == 0) {
            char *end;
            heap_size = strtol(opt + 9, &end, 0);
            if (*end == 'k' || *end == 'K') {
                heap_size <<= 10;
            } else if (*end == 'm' || *end == 'M') {
                heap_size <<= 20;
            }
        }
        a += 2;
    }
    if (a >= argc) {
        fprintf(stderr, "usage: %s [-X heapsize=N] (-c CODE | FILE.py) [ARGS...]\n", argv[0]);
        return 2;
    }
    // The heap is executable: native code (viper, @native, .mpy) is allocated in it.
    void *heap = mmap(NULL, heap_size, PROT_READ | PROT_WRITE | PROT_EXEC, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (heap == MAP_FAILED) {
        perror("mmap heap");
        return 1;
    }
    gc_init(heap, (char *)heap + heap_size);
    mp_init();

    bool is_code = strcmp(argv[a], "-c") == 0;
    if (is_code && a + 1 >= argc) {
        fprintf(stderr, "-c needs an argument\n");
        return 2;
    }
    const char *src = is_code ? argv[a + 1] : argv[a];

    // sys.path
    if (is_code) {
        path_append("", 0);
    } else {
        const char *slash = strrchr(src, '/');
        if (slash) {
            path_append(src, slash - src);
        } else {
            path_append("", 0);
        }
    }
    const char *mpp = getenv("MICROPYPATH");
    if (mpp) {
        const char *p = mpp;
        for (;;) {
            const char *q = strchr(p, ':');
            size_t n = q ? (size_t)(q - p) : strlen(p);
            if (n) {
                path_append(p, n);
            }
            if (!q) {
                break;
            }
            p = q + 1;
        }
    }
    path_append(MPY32_LIB, strlen(MPY32_LIB));

    // sys.argv: the script (or "-c") and what follows
    for (int i = is_code ? a + 2 : a; i < argc; i++) {
        mp_obj_list_append(mp_sys_argv, MP_OBJ_NEW_QSTR(qstr_from_str(argv[i])));
    }

    int ret = run(is_code ? lex_str : lex_file, src, !is_code);
    mp_deinit();
    return ret;
}
