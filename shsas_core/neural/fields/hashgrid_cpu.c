/*
 * Multi-resolution hash encoding on the CPU: forward (features and their spatial Jacobian) and
 * the first-order backward to the table, one pass per (point, level) with the 8 corner values
 * held in registers.
 *
 * The maths is exactly that of shsas_core/fields/encoding.py (encode_fused): the same cell
 * lookup (u * N_l in float32, last cell clamped), the same rows (dense strides or the
 * Instant-NGP hash, masked to the table size, plus the level offset), the same nested lerps.
 * The PyTorch version builds every intermediate as a full (F, 8, P, L) tensor and spends most of
 * its time writing and reading them; here they never leave the registers.
 *
 * Layouts (all row-major, float32):
 *   u      (P, 3)       points in [0, 1]^3
 *   table  (N, F)       vertex features
 *   out    (P, L*F)     level-major features: out[p, l*F + f]
 *   jac    (3, P, L*F)  d out / d u_a
 *   g_tab  (N, F)       table gradient (accumulated into; one private copy per extra thread)
 *
 * Threads: points are split into T contiguous ranges (pthreads, static, so the sums are the
 * same from run to run for the same T). The backward scatter goes to a private table per
 * thread (thread 0 writes g_tab itself), then the copies are added into g_tab by row ranges.
 *
 * Built by shsas_core/fields/native.py with the system C compiler and loaded through ctypes;
 * no Python or torch headers are needed.
 */
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <string.h>

typedef struct {
    int64_t n_levels, n_features, mask;
    const float *res;       /* (L,) grid resolution N_l */
    const int64_t *mult;    /* (L, 3) dense strides or hash primes */
    const int64_t *offsets; /* (L,) first table row of each level */
    const uint8_t *dense;   /* (L,) 1: dense level (sum of strides), 0: hashed (xor, masked) */
} Layout;

static inline void cell(const Layout *lay, int64_t l, const float *u, int64_t rows[8], float fr[3])
{
    const float n = lay->res[l];
    int64_t lo[3];
    for (int a = 0; a < 3; ++a) {
        /* the caller clamps u to [0, 1]; NaN survives a clamp, and a NaN cast to an integer
         * would index outside the table, so it reads the origin's cell here (the field zeroes
         * such points anyway) */
        float ua = u[a];
        if (!(ua >= 0.0f)) ua = 0.0f;
        if (ua > 1.0f) ua = 1.0f;
        const float xs = ua * n;
        /* xs >= 0, so truncation is floor (floorf is a libm call on baseline x86-64, a third of
         * the cost of this function) */
        float c = (float)(int64_t)xs;
        if (c > n - 1.0f) c = n - 1.0f;
        if (c < 0.0f) c = 0.0f;
        fr[a] = xs - c;
        lo[a] = (int64_t)c;
    }
    const int64_t *m = lay->mult + 3 * l;
    const int64_t off = lay->offsets[l];
    for (int c = 0; c < 8; ++c) {
        const int64_t i = lo[0] + (c & 1), j = lo[1] + ((c >> 1) & 1), k = lo[2] + ((c >> 2) & 1);
        int64_t r;
        if (lay->dense[l]) {
            r = i * m[0] + j * m[1] + k * m[2];
        } else {
            const uint64_t h = ((uint64_t)i * (uint64_t)m[0]) ^ ((uint64_t)j * (uint64_t)m[1]) ^
                               ((uint64_t)k * (uint64_t)m[2]);
            r = (int64_t)(h & (uint64_t)lay->mask);
        }
        rows[c] = r + off;
    }
}

/* Points per block. Within a block the levels run outermost, so one level's slice of the table
 * (at most 2^log2_table_size rows) and the block's outputs stay in the L2 cache while its
 * points gather from it: point-major order missed the cache on every corner. */
#define CHUNK 512

/* Points p in [w->p0, w->p1) in blocks of CHUNK, every level l within a block (see CHUNK). */
#define FOR_BLOCKED_POINT_LEVEL(w, nl, p, l)                                           \
    for (int64_t q0_ = (w)->p0; q0_ < (w)->p1; q0_ += CHUNK)                            \
        for (int64_t l = 0; l < (nl); ++l)                                              \
            for (int64_t p = q0_, pe_ = q0_ + CHUNK < (w)->p1 ? q0_ + CHUNK : (w)->p1; \
                 p < pe_; ++p)

typedef struct {
    const Layout *lay;
    const float *u, *table, *g_out, *g_jac;
    float *out, *jac, *g_tab;
    int64_t p0, p1, n_points, n_rows;
    /* reduction: this thread adds the private tables into g_tab rows [r0, r1) */
    float *const *privates;
    int64_t n_privates, r0, r1;
} Work;

static void *forward_range(void *arg)
{
    const Work *w = (const Work *)arg;
    const Layout *lay = w->lay;
    const int64_t nl = lay->n_levels, nf = lay->n_features, d = nl * nf;
    const int64_t plane = w->n_points * d;
    FOR_BLOCKED_POINT_LEVEL(w, nl, p, l) {
        int64_t rows[8];
        float fr[3];
        cell(lay, l, w->u + 3 * p, rows, fr);
        const float n = lay->res[l];
        {
            for (int64_t f = 0; f < nf; ++f) {
                float v[8];
                for (int c = 0; c < 8; ++c) v[c] = w->table[rows[c] * nf + f];
                /* x, then y, then z, as _lerp_forward */
                float dx[4], a[4];
                for (int q = 0; q < 4; ++q) {
                    dx[q] = v[2 * q + 1] - v[2 * q];
                    a[q] = v[2 * q] + fr[0] * dx[q];
                }
                const float dy0 = a[1] - a[0], dy1 = a[3] - a[2];
                const float b0 = a[0] + fr[1] * dy0, b1 = a[2] + fr[1] * dy1;
                const float dz = b1 - b0;
                const int64_t o = p * d + l * nf + f;
                w->out[o] = b0 + fr[2] * dz;
                if (w->jac) {
                    const float cx0 = dx[0] + fr[1] * (dx[1] - dx[0]);
                    const float cx1 = dx[2] + fr[1] * (dx[3] - dx[2]);
                    w->jac[o] = (cx0 + fr[2] * (cx1 - cx0)) * n;
                    w->jac[plane + o] = (dy0 + fr[2] * (dy1 - dy0)) * n;
                    w->jac[2 * plane + o] = dz * n;
                }
            }
        }
    }
    return NULL;
}

static void *backward_range(void *arg)
{
    const Work *w = (const Work *)arg;
    const Layout *lay = w->lay;
    const int64_t nl = lay->n_levels, nf = lay->n_features, d = nl * nf;
    const int64_t plane = w->n_points * d;
    const float *restrict g_out = w->g_out, *restrict g_jac = w->g_jac;
    float *restrict g = w->g_tab;
    FOR_BLOCKED_POINT_LEVEL(w, nl, p, l) {
        int64_t rows[8];
        float fr[3];
        cell(lay, l, w->u + 3 * p, rows, fr);
        const float n = lay->res[l];
        {
            /* d out / d v_c = Wz Wy Wx and d jac_a / d v_c (slope S = n (-1, +1) on axis a), with
             * per-axis weights W = (1 - f, f): the same for every feature, so built once */
            const float wx[2] = {1.0f - fr[0], fr[0]}, wy[2] = {1.0f - fr[1], fr[1]},
                        wz[2] = {1.0f - fr[2], fr[2]};
            const float s[2] = {-n, n};
            float c_out[8], c_x[8], c_y[8], c_z[8];
            for (int c = 0; c < 8; ++c) {
                const int cx = c & 1, cy = (c >> 1) & 1, cz = (c >> 2) & 1;
                c_out[c] = wx[cx] * wy[cy] * wz[cz];
                c_x[c] = s[cx] * wy[cy] * wz[cz];
                c_y[c] = wx[cx] * s[cy] * wz[cz];
                c_z[c] = wx[cx] * wy[cy] * s[cz];
            }
            for (int64_t f = 0; f < nf; ++f) {
                const int64_t o = p * d + l * nf + f;
                const float go = g_out[o];
                if (g_jac) {
                    const float gx = g_jac[o], gy = g_jac[plane + o], gz = g_jac[2 * plane + o];
                    for (int c = 0; c < 8; ++c)
                        g[rows[c] * nf + f] += go * c_out[c] + gx * c_x[c] + gy * c_y[c] + gz * c_z[c];
                } else {
                    for (int c = 0; c < 8; ++c) g[rows[c] * nf + f] += go * c_out[c];
                }
            }
        }
    }
    return NULL;
}

static void *reduce_range(void *arg)
{
    const Work *w = (const Work *)arg;
    const int64_t nf = w->lay->n_features;
    for (int64_t t = 0; t < w->n_privates; ++t) {
        const float *src = w->privates[t];
        for (int64_t i = w->r0 * nf; i < w->r1 * nf; ++i) w->g_tab[i] += src[i];
    }
    return NULL;
}

#define MAX_THREADS 256

/* Run fn over T workers: T - 1 new threads and the calling one. Returns 0, or -1 when a thread
 * could not be created (the work of that range is then done by the caller, so the result is
 * still complete). */
static int run_parallel(void *(*fn)(void *), Work *works, int64_t n_threads)
{
    pthread_t tid[MAX_THREADS];
    int started[MAX_THREADS];
    int status = 0;
    for (int64_t t = 1; t < n_threads; ++t) {
        started[t] = pthread_create(&tid[t], NULL, fn, &works[t]) == 0;
        if (!started[t]) status = -1;
    }
    fn(&works[0]);
    for (int64_t t = 1; t < n_threads; ++t) {
        if (started[t]) pthread_join(tid[t], NULL);
        else fn(&works[t]);
    }
    return status;
}

static int64_t clamp_threads(int64_t n_threads, int64_t n_points)
{
    if (n_threads < 1) n_threads = 1;
    if (n_threads > MAX_THREADS) n_threads = MAX_THREADS;
    /* below ~16k points per thread the thread start costs more than it saves (measured: 4k
     * points took 1.7 ms on one thread and 1.8 ms on two) */
    const int64_t useful = n_points / 16384 + 1;
    return n_threads < useful ? n_threads : useful;
}

/* The fields every worker shares, and its contiguous point range [p0, p1). */
static void init_works(Work *works, int64_t n_threads, const Layout *lay, const float *u, int64_t n)
{
    for (int64_t t = 0; t < n_threads; ++t) {
        memset(&works[t], 0, sizeof(Work));
        works[t].lay = lay;
        works[t].u = u;
        works[t].n_points = n;
        works[t].p0 = n * t / n_threads;
        works[t].p1 = n * (t + 1) / n_threads;
    }
}

int shsas_hash_forward(int64_t n_points, const float *u, const float *table, int64_t n_levels,
                       int64_t n_features, const float *res, const int64_t *mult,
                       const int64_t *offsets, const uint8_t *dense, int64_t mask, float *out,
                       float *jac, int64_t n_threads)
{
    const Layout lay = {n_levels, n_features, mask, res, mult, offsets, dense};
    Work works[MAX_THREADS];
    n_threads = clamp_threads(n_threads, n_points);
    init_works(works, n_threads, &lay, u, n_points);
    for (int64_t t = 0; t < n_threads; ++t) {
        works[t].table = table;
        works[t].out = out;
        works[t].jac = jac;
    }
    return run_parallel(forward_range, works, n_threads);
}

/* privates: (n_threads - 1) zeroed (N, F) scratch tables; the caller allocates them (it knows
 * how many threads it asked for: shsas_hash_threads). g_tab must be zeroed (or hold a sum to
 * add to). */
int shsas_hash_backward(int64_t n_points, const float *u, const float *g_out, const float *g_jac,
                        int64_t n_levels, int64_t n_features, const float *res,
                        const int64_t *mult, const int64_t *offsets, const uint8_t *dense,
                        int64_t mask, int64_t n_rows, float *g_tab, float *const *privates,
                        int64_t n_threads)
{
    const Layout lay = {n_levels, n_features, mask, res, mult, offsets, dense};
    Work works[MAX_THREADS];
    n_threads = clamp_threads(n_threads, n_points);
    init_works(works, n_threads, &lay, u, n_points);
    for (int64_t t = 0; t < n_threads; ++t) {
        works[t].g_out = g_out;
        works[t].g_jac = g_jac;
        works[t].g_tab = t == 0 ? g_tab : privates[t - 1];
        works[t].n_rows = n_rows;
    }
    int status = run_parallel(backward_range, works, n_threads);
    if (n_threads > 1) {
        for (int64_t t = 0; t < n_threads; ++t) {
            works[t].g_tab = g_tab;
            works[t].privates = privates;
            works[t].n_privates = n_threads - 1;
            works[t].r0 = n_rows * t / n_threads;
            works[t].r1 = n_rows * (t + 1) / n_threads;
        }
        status |= run_parallel(reduce_range, works, n_threads);
    }
    return status;
}

/* The number of workers shsas_hash_forward/backward use for n_points with n_threads asked. */
int64_t shsas_hash_threads(int64_t n_threads, int64_t n_points)
{
    return clamp_threads(n_threads, n_points);
}
