/*
 * QEMU TCG plugin: execution count of every translated block (`xtask/src/cpi.rs`).
 *
 * For each block QEMU translates, an inline counter is added to the block's entry; at exit the
 * plugin writes one line per translation, `<guest address hex> <instructions> <executions>`,
 * to the file given as `out=<path>`. A block retranslated at the same address gives several
 * lines (the reader sums them). Inline counting adds host code only: the guest's instruction
 * count, hence `-icount` virtual time, is unchanged.
 *
 * Built by `cargo xtask timing` with the host C compiler. The plugin API of QEMU 7.2
 * (`include/qemu/qemu-plugin.h`, API version 1) is declared here by hand because Debian ships
 * no development header for it; only the calls below are used.
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef uint64_t qemu_plugin_id_t;
struct qemu_plugin_tb;
typedef struct qemu_info_t qemu_info_t;
enum qemu_plugin_op { QEMU_PLUGIN_INLINE_ADD_U64 };
typedef void (*qemu_plugin_vcpu_tb_trans_cb_t)(qemu_plugin_id_t id, struct qemu_plugin_tb *tb);
typedef void (*qemu_plugin_udata_cb_t)(qemu_plugin_id_t id, void *userdata);

extern void qemu_plugin_register_vcpu_tb_trans_cb(qemu_plugin_id_t id,
                                                  qemu_plugin_vcpu_tb_trans_cb_t cb);
extern void qemu_plugin_register_vcpu_tb_exec_inline(struct qemu_plugin_tb *tb,
                                                     enum qemu_plugin_op op, void *ptr,
                                                     uint64_t imm);
extern void qemu_plugin_register_atexit_cb(qemu_plugin_id_t id, qemu_plugin_udata_cb_t cb,
                                           void *userdata);
extern uint64_t qemu_plugin_tb_vaddr(const struct qemu_plugin_tb *tb);
extern size_t qemu_plugin_tb_n_insns(const struct qemu_plugin_tb *tb);

__attribute__((visibility("default"))) int qemu_plugin_version = 1;

/* One translated block. Blocks are never freed: their counters must outlive the translation. */
struct block {
    uint64_t vaddr;
    uint64_t insns;
    uint64_t count;
};

/* Blocks in chunks, so that a counter's address never moves. */
#define CHUNK 4096
static struct block **chunks;
static size_t n_chunks, n_blocks;
static char *out_path;

static struct block *new_block(void)
{
    if (n_blocks % CHUNK == 0) {
        struct block **c = realloc(chunks, (n_chunks + 1) * sizeof *chunks);
        if (!c) {
            return NULL;
        }
        chunks = c;
        chunks[n_chunks] = calloc(CHUNK, sizeof(struct block));
        if (!chunks[n_chunks]) {
            return NULL;
        }
        n_chunks++;
    }
    struct block *b = &chunks[n_blocks / CHUNK][n_blocks % CHUNK];
    n_blocks++;
    return b;
}

static void on_translate(qemu_plugin_id_t id, struct qemu_plugin_tb *tb)
{
    (void)id;
    struct block *b = new_block();
    if (!b) {
        return;
    }
    b->vaddr = qemu_plugin_tb_vaddr(tb);
    b->insns = qemu_plugin_tb_n_insns(tb);
    qemu_plugin_register_vcpu_tb_exec_inline(tb, QEMU_PLUGIN_INLINE_ADD_U64, &b->count, 1);
}

static void write_counts(qemu_plugin_id_t id, void *userdata)
{
    (void)id;
    (void)userdata;
    FILE *f = fopen(out_path, "w");
    if (!f) {
        return;
    }
    for (size_t i = 0; i < n_blocks; i++) {
        const struct block *b = &chunks[i / CHUNK][i % CHUNK];
        if (b->count) {
            fprintf(f, "%llx %llu %llu\n", (unsigned long long)b->vaddr,
                    (unsigned long long)b->insns, (unsigned long long)b->count);
        }
    }
    fclose(f);
}

__attribute__((visibility("default"))) int qemu_plugin_install(qemu_plugin_id_t id,
                                                               const qemu_info_t *info,
                                                               int argc, char **argv)
{
    (void)info;
    for (int i = 0; i < argc; i++) {
        if (strncmp(argv[i], "out=", 4) == 0) {
            out_path = strdup(argv[i] + 4);
        }
    }
    if (!out_path) {
        fprintf(stderr, "block_count: missing out=<path>\n");
        return -1;
    }
    qemu_plugin_register_vcpu_tb_trans_cb(id, on_translate);
    qemu_plugin_register_atexit_cb(id, write_counts, NULL);
    return 0;
}
