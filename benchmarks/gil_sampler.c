/* benchmarks/thread_cpu.py --gil (issue 23, session 33): a thread that reads CPython's GIL "locked"
   flag at random times (0-2 us apart while it has a core) together with the CPU clock of the thread
   that started it (on another core), and adds up that thread's CPU since the last read: all of it,
   and that followed by a read of 1, in steps of at most 50 us of its CPU. The share of the reads
   that found the GIL held is then the share of that thread's CPU with the GIL held, over any
   interval the caller reads (long enough to hold many reads: on a loaded machine the sampler gets
   its core a fraction of the time). Time the thread spends off its core adds no CPU, so the load
   does not bias the share. No Python API. */
#define _GNU_SOURCE
#include <pthread.h>
#include <sched.h>
#include <stdatomic.h>
#include <time.h>
static volatile int *flag;
static volatile int running;
static clockid_t target;
static _Atomic unsigned long long t_all, t_held;
static pthread_t th;
#define MAX_STEP 50000ull /* ns of the measured thread's CPU between two reads */
static unsigned long long now(void) {
    struct timespec ts;
    clock_gettime(target, &ts);
    return (unsigned long long)ts.tv_sec * 1000000000ull + (unsigned long long)ts.tv_nsec;
}
static void *loop(void *arg) {
    (void)arg;
    unsigned long long c0 = now(), rnd = 88172645463325252ull;
    while (running) {
        /* the thread's CPU since the last read, counted held when the flag reads 1 now: read at
           random times (below), the flag's share of the reads is its share of the CPU */
        unsigned long long c = now();
        int v = *flag;
        /* only short steps: after a long one (the sampler was off its core) the flag reads as the
           measured thread left it if that one is off its core too, e.g. preempted at a system
           call's return with the GIL held: that state would get all of the step's CPU */
        if (c - c0 < MAX_STEP) {
            atomic_fetch_add_explicit(&t_all, c - c0, memory_order_relaxed);
            if (v) atomic_fetch_add_explicit(&t_held, c - c0, memory_order_relaxed);
        }
        c0 = c;
        /* a random wait of 0-2 us: a fixed period can lock onto a loop's and read one phase of it */
        rnd ^= rnd << 13, rnd ^= rnd >> 7, rnd ^= rnd << 17;
        for (unsigned k = rnd % 512; k; k--) __builtin_ia32_pause();
    }
    return 0;
}
/* called by the thread to measure (its CPU clock); addr: the GIL's locked flag; cpu: the core the
   sampler runs on (the caller pins itself to another: sharing a core, the sampler would read the
   flag only while the measured thread is off it, as it was when preempted) */
int gs_start(void *addr, int cpu) {
    cpu_set_t set;
    flag = (volatile int *)addr;
    pthread_getcpuclockid(pthread_self(), &target);
    running = 1;
    if (pthread_create(&th, 0, loop, 0)) return -1;
    CPU_ZERO(&set);
    CPU_SET(cpu, &set);
    return pthread_setaffinity_np(th, sizeof(set), &set);
}
void gs_stop(void) { running = 0; pthread_join(th, 0); }
void gs_read(unsigned long long *out) { out[0] = atomic_load(&t_all); out[1] = atomic_load(&t_held); }
