/* armcount: a qemu-user TCG plugin that counts the guest (ARM) instructions a program executes,
 * split by stage and by the library the code belongs to.
 *
 * Stages: the guest switches the current stage with a system call that does not exist,
 * syscall(ARMCOUNT_SYSCALL, stage) (qemu answers ENOSYS, the plugin sees the call first); stage 0
 * is where a program starts. Libraries: each translated block is attributed to the file mapped at
 * its host address (qemu-user maps guest code from the guest's .so files), so the output tells
 * OpenCV from numpy from the interpreter.
 *
 * Written against the public plugin API of qemu 7.2 (qemu-plugin.h, API version 1; Debian ships no
 * header for it, so the few declarations used are repeated below). Every thread's instructions
 * are added atomically. At exit it writes lines "stage <n> <library> <instructions>" and
 * "total <instructions>" to $ARMCOUNT_OUT (or stderr).
 *
 * Processes: qemu-user runs a forked child (multiprocessing's workers) in a fork of itself, plugin
 * included. The child starts counting from zero (the parent's instructions before the fork stay the
 * parent's) and writes its own counts to $ARMCOUNT_OUT.<pid>, so each process is counted apart.
 *
 * Build: gcc -shared -fPIC -O2 -o armcount.so armcount.c
 * Run:   ARMCOUNT_OUT=counts.txt qemu-arm -plugin ./armcount.so -L ROOT ROOT/usr/bin/python3.11 ...
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <stddef.h>
#include <pthread.h>
#include <unistd.h>

/* --- from qemu-plugin.h (API version 1) --- */
typedef uint64_t qemu_plugin_id_t;
struct qemu_plugin_tb;
struct qemu_plugin_insn;
enum qemu_plugin_cb_flags { QEMU_PLUGIN_CB_NO_REGS, QEMU_PLUGIN_CB_R_REGS, QEMU_PLUGIN_CB_RW_REGS };
typedef void (*qemu_plugin_vcpu_tb_trans_cb_t)(qemu_plugin_id_t id, struct qemu_plugin_tb *tb);
typedef void (*qemu_plugin_vcpu_udata_cb_t)(unsigned int vcpu_index, void *userdata);
typedef void (*qemu_plugin_udata_cb_t)(qemu_plugin_id_t id, void *userdata);
typedef void (*qemu_plugin_vcpu_syscall_cb_t)(qemu_plugin_id_t id, unsigned int vcpu_index, int64_t num,
                                              uint64_t a1, uint64_t a2, uint64_t a3, uint64_t a4,
                                              uint64_t a5, uint64_t a6, uint64_t a7, uint64_t a8);
typedef void (*qemu_plugin_vcpu_syscall_ret_cb_t)(qemu_plugin_id_t id, unsigned int vcpu_idx, int64_t num,
                                                  int64_t ret);
void qemu_plugin_register_vcpu_tb_trans_cb(qemu_plugin_id_t id, qemu_plugin_vcpu_tb_trans_cb_t cb);
void qemu_plugin_register_vcpu_tb_exec_cb(struct qemu_plugin_tb *tb, qemu_plugin_vcpu_udata_cb_t cb,
                                          enum qemu_plugin_cb_flags flags, void *userdata);
void qemu_plugin_register_vcpu_syscall_cb(qemu_plugin_id_t id, qemu_plugin_vcpu_syscall_cb_t cb);
void qemu_plugin_register_vcpu_syscall_ret_cb(qemu_plugin_id_t id, qemu_plugin_vcpu_syscall_ret_cb_t cb);
void qemu_plugin_register_atexit_cb(qemu_plugin_id_t id, qemu_plugin_udata_cb_t cb, void *userdata);
size_t qemu_plugin_tb_n_insns(const struct qemu_plugin_tb *tb);
struct qemu_plugin_insn *qemu_plugin_tb_get_insn(const struct qemu_plugin_tb *tb, size_t idx);
void *qemu_plugin_insn_haddr(const struct qemu_plugin_insn *insn);
__attribute__((visibility("default"))) int qemu_plugin_version = 1;
/* --- end of qemu-plugin.h --- */

#define ARMCOUNT_SYSCALL 0xC0DE   /* no such ARM system call; below the ARM-private 0xf0000 range */
/* ARM EABI calls that change the memory map: munmap, mremap, mprotect, mmap2 */
#define IS_MAP_CALL(n) ((n) == 91 || (n) == 163 || (n) == 125 || (n) == 192)
/* ARM EABI calls that can make a process: fork, clone, vfork */
#define IS_FORK_CALL(n) ((n) == 2 || (n) == 120 || (n) == 190)
#define MAX_STAGES 64
#define MAX_LIBS 1024                          /* OpenCV alone pulls in ~150 libraries */

struct block { uint64_t n; unsigned lib; };
struct mapping { uintptr_t lo, hi; unsigned lib; };

static uint64_t counts[MAX_STAGES][MAX_LIBS];
static unsigned stage;                         /* current stage, set by the guest */
static char *lib_names[MAX_LIBS];
static unsigned n_libs;
static struct mapping *maps;
static size_t n_maps;
static int maps_stale = 1;                     /* the guest mapped or unmapped memory since */
static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static pid_t counted_pid;                      /* the process these counts belong to */
static int forked;                             /* this process is a fork of the one qemu started */

static unsigned lib_index(const char *name)
{
    for (unsigned i = 0; i < n_libs; i++)
        if (strcmp(lib_names[i], name) == 0)
            return i;
    if (n_libs >= MAX_LIBS - 1) {              /* the last bucket takes any overflow */
        if (n_libs == MAX_LIBS - 1)
            lib_names[n_libs++] = strdup("[more]");
        return MAX_LIBS - 1;
    }
    lib_names[n_libs] = strdup(name);
    return n_libs++;
}

/* Re-reads the host's memory map: file-backed executable mappings, named by their basename. */
static void read_maps(void)
{
    FILE *f = fopen("/proc/self/maps", "r");
    char line[4096];
    size_t cap = 0;
    n_maps = 0;
    if (!f)
        return;
    while (fgets(line, sizeof line, f)) {
        unsigned long lo, hi;
        char perms[8], path[3072] = "";
        if (sscanf(line, "%lx-%lx %7s %*s %*s %*s %3071[^\n]", &lo, &hi, perms, path) < 3)
            continue;
        if (n_maps == cap) {
            cap = cap ? 2 * cap : 256;
            maps = realloc(maps, cap * sizeof *maps);
        }
        const char *base = strrchr(path, '/');
        base = base ? base + 1 : (path[0] ? path : "[anon]");
        maps[n_maps++] = (struct mapping){lo, hi, lib_index(base)};
    }
    fclose(f);
}

static int find_lib(uintptr_t addr, unsigned *lib)
{
    for (size_t i = 0; i < n_maps; i++)
        if (addr >= maps[i].lo && addr < maps[i].hi) {
            *lib = maps[i].lib;
            return 1;
        }
    return 0;
}

static unsigned lib_of(uintptr_t addr)
{
    unsigned lib;
    pthread_mutex_lock(&lock);
    if (__atomic_exchange_n(&maps_stale, 0, __ATOMIC_RELAXED))
        read_maps();                           /* a library may have been loaded since the last look */
    if (!find_lib(addr, &lib))
        lib = lib_index("[unknown]");
    pthread_mutex_unlock(&lock);
    return lib;
}

static void on_exec(unsigned int vcpu, void *udata)
{
    struct block *b = udata;
    unsigned s = __atomic_load_n(&stage, __ATOMIC_RELAXED);
    __atomic_fetch_add(&counts[s][b->lib], b->n, __ATOMIC_RELAXED);
}

static void on_translate(qemu_plugin_id_t id, struct qemu_plugin_tb *tb)
{
    struct block *b = malloc(sizeof *b);      /* lives as long as the translation may run */
    size_t n = qemu_plugin_tb_n_insns(tb);
    void *haddr = n ? qemu_plugin_insn_haddr(qemu_plugin_tb_get_insn(tb, 0)) : NULL;
    b->n = n;
    b->lib = lib_of((uintptr_t)haddr);
    qemu_plugin_register_vcpu_tb_exec_cb(tb, on_exec, QEMU_PLUGIN_CB_NO_REGS, b);
}

static void on_syscall(qemu_plugin_id_t id, unsigned int vcpu, int64_t num, uint64_t a1, uint64_t a2,
                       uint64_t a3, uint64_t a4, uint64_t a5, uint64_t a6, uint64_t a7, uint64_t a8)
{
    if (num == ARMCOUNT_SYSCALL && a1 < MAX_STAGES)
        __atomic_store_n(&stage, (unsigned)a1, __ATOMIC_RELAXED);
    else if (IS_MAP_CALL(num))
        __atomic_store_n(&maps_stale, 1, __ATOMIC_RELAXED);
}

/* A fork or clone returned 0 in a new process (a thread keeps its pid): count it from zero. */
static void on_syscall_ret(qemu_plugin_id_t id, unsigned int vcpu, int64_t num, int64_t ret)
{
    if (!IS_FORK_CALL(num) || ret != 0 || getpid() == counted_pid)
        return;
    counted_pid = getpid();
    forked = 1;
    pthread_mutex_init(&lock, NULL);           /* another thread may have held it at the fork */
    memset(counts, 0, sizeof counts);
}

static void write_counts(qemu_plugin_id_t id, void *p)
{
    const char *out = getenv("ARMCOUNT_OUT");
    char path[4096];
    FILE *f = stderr;
    if (out) {
        if (forked)
            snprintf(path, sizeof path, "%s.%d", out, (int)getpid());
        else
            snprintf(path, sizeof path, "%s", out);
        f = fopen(path, "w");
    }
    uint64_t total = 0;
    if (!f)
        return;
    for (unsigned s = 0; s < MAX_STAGES; s++)
        for (unsigned l = 0; l < n_libs; l++) {
            uint64_t c = __atomic_load_n(&counts[s][l], __ATOMIC_RELAXED);
            if (c) {
                fprintf(f, "stage %u %s %llu\n", s, lib_names[l], (unsigned long long)c);
                total += c;
            }
        }
    fprintf(f, "total %llu\n", (unsigned long long)total);
    if (out)
        fclose(f);
}

__attribute__((visibility("default")))
int qemu_plugin_install(qemu_plugin_id_t id, const void *info, int argc, char **argv)
{
    counted_pid = getpid();
    qemu_plugin_register_vcpu_tb_trans_cb(id, on_translate);
    qemu_plugin_register_vcpu_syscall_cb(id, on_syscall);
    qemu_plugin_register_vcpu_syscall_ret_cb(id, on_syscall_ret);
    qemu_plugin_register_atexit_cb(id, write_counts, NULL);
    return 0;
}
