/*
 * cyclone_peer: a Cyclone DDS 0.10 publisher/subscriber that Courier's interop
 * tests run against Courier's own RTPS backend.
 *
 * Loopback only: the program always creates its domain from the built-in
 * LOOPBACK_CONFIG below (interface lo, no multicast, unicast SPDP to
 * 127.0.0.1), passed to dds_create_domain(); CYCLONEDDS_URI is ignored and
 * unset. There is no way to run it with any other network configuration.
 *
 * Command line and output: see usage(). The
 * Fast DDS peer (fastdds_peer.cpp) takes the same flags and prints the same
 * lines.
 *
 * Build (tests/peers.rs and sdk/tests/rtps_interop.rs do this; README.md
 * beside this file documents it): idlc -x final types.idl, then
 *   cc -std=gnu11 -O2 cyclone_peer.c types.c $(pkg-config --cflags --libs CycloneDDS)
 */
#define _GNU_SOURCE
#include <errno.h>
#include <inttypes.h>
#include <limits.h>
#include <poll.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "dds/dds.h"
#include "types.h"

#define EXIT_RUNTIME 1
#define EXIT_TIMEOUT 2
#define EXIT_ORPHANED 3
#define EXIT_USAGE 64

#define MAX_SIZES 64
#define MAX_DOMAIN 232 /* 7400 + 250 * d + 61 must stay below 65536 */

/* Loopback-only, unicast-only discovery; valid for any domain id. Same
 * settings as tests/peers/rtps/cyclone-unicast-lo.xml. The first %s is an
 * optional <Internal> element (--keyhash), the second an optional <Tracing>
 * element (--trace FILE). */
static const char LOOPBACK_CONFIG[] =
    "<CycloneDDS><Domain id=\"any\">"
    "<General><Interfaces><NetworkInterface name=\"lo\"/></Interfaces>"
    "<AllowMulticast>false</AllowMulticast></General>"
    "<Discovery><ParticipantIndex>auto</ParticipantIndex>"
    "<MaxAutoParticipantIndex>20</MaxAutoParticipantIndex>"
    "<Peers><Peer address=\"127.0.0.1\"/></Peers></Discovery>"
    "%s"
    "%s"
    "</Domain></CycloneDDS>";

/* --keyhash: writers of keyed topics send PID_KEY_HASH with every sample and
 * dispose (Cyclone DDS 0.10 computes it in the XCDR version of the data). */
static const char KEYHASH_CONFIG[] = "<Internal><GenerateKeyhash>true</GenerateKeyhash></Internal>";

/* The `stamp` key of instance `id` of a `stamped` sample. */
#define STAMP_BASE INT64_C(0x0102030405060708)

enum type_kind { TYPE_NONE, TYPE_MSG, TYPE_KEYED, TYPE_STRKEYED, TYPE_STAMPED };

struct options {
  long domain;
  const char *topic;
  enum type_kind type;
  int role;        /* 0 unset, 1 pub, 2 sub */
  int reliability; /* 0 unset, 1 reliable, 2 best effort */
  bool transient_local;
  long depth;
  bool depth_set;
  bool keep_all;
  long count;
  bool count_set;
  long sizes[MAX_SIZES];
  int nsizes;
  long period_ms;
  long dispose_every;
  long wait_match;
  bool wait_stdin;
  long timeout_s;
  long linger_ms;
  long settle_ms;
  bool settle_set;
  long keys;
  bool no_autodispose;
  long disposed;
  bool disposed_set;
  const char *text;
  const char *trace;
  bool keyhash;
};

static const char *prog = "cyclone_peer";
static struct timespec start_time;
static pid_t initial_ppid;

static void usage(FILE *out)
{
  fprintf(out,
      "usage: %s --domain N --topic NAME --type msg|keyed|strkeyed|stamped --pub|--sub\n"
      "          --reliable|--best-effort [--transient-local]\n"
      "          [--depth N (keep last, default 10) | --keep-all] [--count N]\n"
      "          [--size BYTES[,BYTES...]] [--period-ms N] [--dispose-every N]\n"
      "          [--wait-match N] [--wait-stdin] [--settle-ms N] [--timeout-s N] [--linger-ms N]\n"
      "          [--keys N] [--disposed N] [--no-autodispose] [--text PREFIX] [--trace FILE]\n"
      "          [--keyhash]\n"
      "Loopback only (interface lo, unicast discovery to 127.0.0.1).\n"
      "--keyhash: writers send PID_KEY_HASH (Internal/GenerateKeyhash).\n"
      "--type stamped: @key long id; @key long long stamp (0x0102030405060708 + id);\n"
      "  its instances are named <id>:<stamp> in sample, disposed and unregistered lines.\n"
      "A subscriber is done after --count samples and --disposed disposals (both when\n"
      "given, otherwise it runs until --timeout-s); either role then stays --linger-ms.\n"
      "Output lines: ready | matched <n> | sent <seq> | sent <id> <seq> | dispose <id>\n"
      "  | acked | sample <seq> <text> <len> <fnv1a32> | sample <id> <seq> <text>\n"
      "  | disposed <id> | unregistered <id> | done | timeout\n"
      "Exit: 0 done, 1 DDS error, 2 timeout, 3 parent gone, 64 usage.\n",
      prog);
}

static void usage_error(const char *fmt, ...)
{
  va_list ap;
  fprintf(stderr, "%s: usage error: ", prog);
  va_start(ap, fmt);
  vfprintf(stderr, fmt, ap);
  va_end(ap);
  fputc('\n', stderr);
  usage(stderr);
  exit(EXIT_USAGE);
}

static void fail(const char *what, dds_return_t rc)
{
  fprintf(stderr, "%s: error: %s: %s\n", prog, what, dds_strretcode(rc));
  exit(EXIT_RUNTIME);
}

static void emit(const char *fmt, ...)
{
  va_list ap;
  va_start(ap, fmt);
  vfprintf(stdout, fmt, ap);
  va_end(ap);
  fputc('\n', stdout);
  fflush(stdout);
}

static long parse_num(const char *flag, const char *arg, long min, long max)
{
  char *end;
  long v;
  if (arg == NULL)
    usage_error("%s needs a value", flag);
  errno = 0;
  v = strtol(arg, &end, 10);
  if (errno != 0 || end == arg || *end != '\0' || v < min || v > max)
    usage_error("%s: '%s' is not an integer in %ld..%ld", flag, arg, min, max);
  return v;
}

static void parse_sizes(struct options *o, const char *arg)
{
  const char *p = arg;
  char buf[32];
  if (arg == NULL)
    usage_error("--size needs a value");
  o->nsizes = 0;
  while (*p) {
    size_t n = strcspn(p, ",");
    if (n == 0 || n >= sizeof buf || o->nsizes == MAX_SIZES)
      usage_error("--size: bad list '%s'", arg);
    memcpy(buf, p, n);
    buf[n] = '\0';
    o->sizes[o->nsizes++] = parse_num("--size", buf, 0, 64L * 1024 * 1024);
    p += n;
    if (*p == ',') {
      p++;
      if (*p == '\0')
        usage_error("--size: bad list '%s'", arg);
    }
  }
  if (o->nsizes == 0)
    usage_error("--size: empty list");
}

static void parse_args(int argc, char **argv, struct options *o)
{
  memset(o, 0, sizeof *o);
  o->domain = -1;
  o->depth = 10;
  o->timeout_s = 60;
  o->settle_ms = 250;
  for (int i = 1; i < argc; i++) {
    const char *a = argv[i];
    const char *v = (i + 1 < argc) ? argv[i + 1] : NULL;
#define TAKES_VALUE() (i++, v)
    if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
      usage(stdout);
      exit(0);
    } else if (strcmp(a, "--domain") == 0) {
      o->domain = parse_num(a, TAKES_VALUE(), 0, MAX_DOMAIN);
    } else if (strcmp(a, "--topic") == 0) {
      o->topic = TAKES_VALUE();
      if (o->topic == NULL || o->topic[0] == '\0')
        usage_error("--topic needs a non-empty name");
    } else if (strcmp(a, "--type") == 0) {
      const char *t = TAKES_VALUE();
      if (t == NULL)
        usage_error("--type needs a value");
      if (strcmp(t, "msg") == 0)
        o->type = TYPE_MSG;
      else if (strcmp(t, "keyed") == 0)
        o->type = TYPE_KEYED;
      else if (strcmp(t, "strkeyed") == 0)
        o->type = TYPE_STRKEYED;
      else if (strcmp(t, "stamped") == 0)
        o->type = TYPE_STAMPED;
      else
        usage_error("--type must be msg, keyed, strkeyed or stamped, not '%s'", t);
    } else if (strcmp(a, "--pub") == 0 || strcmp(a, "--sub") == 0) {
      int r = (a[2] == 'p') ? 1 : 2;
      if (o->role != 0 && o->role != r)
        usage_error("--pub and --sub are exclusive");
      o->role = r;
    } else if (strcmp(a, "--reliable") == 0 || strcmp(a, "--best-effort") == 0) {
      int r = (a[2] == 'r') ? 1 : 2;
      if (o->reliability != 0 && o->reliability != r)
        usage_error("--reliable and --best-effort are exclusive");
      o->reliability = r;
    } else if (strcmp(a, "--transient-local") == 0) {
      o->transient_local = true;
    } else if (strcmp(a, "--depth") == 0) {
      o->depth = parse_num(a, TAKES_VALUE(), 1, 100000);
      o->depth_set = true;
    } else if (strcmp(a, "--keep-all") == 0) {
      o->keep_all = true;
    } else if (strcmp(a, "--count") == 0) {
      o->count = parse_num(a, TAKES_VALUE(), 0, INT32_MAX);
      o->count_set = true;
    } else if (strcmp(a, "--size") == 0) {
      parse_sizes(o, TAKES_VALUE());
    } else if (strcmp(a, "--period-ms") == 0) {
      o->period_ms = parse_num(a, TAKES_VALUE(), 0, 3600000);
    } else if (strcmp(a, "--dispose-every") == 0) {
      o->dispose_every = parse_num(a, TAKES_VALUE(), 1, INT32_MAX);
    } else if (strcmp(a, "--wait-match") == 0) {
      o->wait_match = parse_num(a, TAKES_VALUE(), 0, 1000);
    } else if (strcmp(a, "--wait-stdin") == 0) {
      o->wait_stdin = true;
    } else if (strcmp(a, "--settle-ms") == 0) {
      o->settle_ms = parse_num(a, TAKES_VALUE(), 0, 3600000);
      o->settle_set = true;
    } else if (strcmp(a, "--timeout-s") == 0) {
      o->timeout_s = parse_num(a, TAKES_VALUE(), 1, 86400);
    } else if (strcmp(a, "--linger-ms") == 0) {
      o->linger_ms = parse_num(a, TAKES_VALUE(), 0, 3600000);
    } else if (strcmp(a, "--keys") == 0) {
      o->keys = parse_num(a, TAKES_VALUE(), 1, INT32_MAX);
    } else if (strcmp(a, "--no-autodispose") == 0) {
      o->no_autodispose = true;
    } else if (strcmp(a, "--disposed") == 0) {
      o->disposed = parse_num(a, TAKES_VALUE(), 0, INT32_MAX);
      o->disposed_set = true;
    } else if (strcmp(a, "--text") == 0) {
      o->text = TAKES_VALUE();
      if (o->text == NULL)
        usage_error("--text needs a value");
    } else if (strcmp(a, "--keyhash") == 0) {
      o->keyhash = true;
    } else if (strcmp(a, "--trace") == 0) {
      o->trace = TAKES_VALUE();
      if (o->trace == NULL || o->trace[0] == '\0' || strpbrk(o->trace, "<>&\"'"))
        usage_error("--trace needs a plain file name");
    } else {
      usage_error("unknown argument '%s'", a);
    }
#undef TAKES_VALUE
  }
  if (o->domain < 0)
    usage_error("--domain is required");
  if (o->topic == NULL)
    usage_error("--topic is required");
  if (o->type == TYPE_NONE)
    usage_error("--type is required");
  if (o->role == 0)
    usage_error("one of --pub or --sub is required");
  if (o->reliability == 0)
    usage_error("one of --reliable or --best-effort is required");
  if (o->keep_all && o->depth_set)
    usage_error("--depth and --keep-all are exclusive");
  if (o->role == 2) {
    if (o->nsizes || o->period_ms || o->dispose_every || o->wait_match || o->wait_stdin ||
        o->settle_set || o->keys || o->no_autodispose || o->text)
      usage_error("--size, --period-ms, --dispose-every, --wait-match, --wait-stdin, "
                  "--settle-ms, --keys, --no-autodispose and --text are publisher options");
    if (o->disposed_set && o->type == TYPE_MSG)
      usage_error("--disposed is for --type keyed, strkeyed or stamped");
  } else {
    if (o->type == TYPE_STRKEYED)
      usage_error("--type strkeyed is for subscribers");
    if (o->disposed_set)
      usage_error("--disposed is a subscriber option");
    if (!o->count_set)
      o->count = 1;
  }
  if (o->type != TYPE_MSG && o->nsizes)
    usage_error("--size is for --type msg");
  if (o->type == TYPE_MSG && (o->dispose_every || o->keys || o->no_autodispose))
    usage_error("--dispose-every, --keys and --no-autodispose are for --type keyed or stamped");
  if (o->nsizes == 0) {
    o->nsizes = 1;
    o->sizes[0] = 0;
  }
  if (o->text == NULL)
    o->text = "cyclone";
}

/* ---- time and lifetime ---- */

static int64_t elapsed_ms(void)
{
  struct timespec now;
  clock_gettime(CLOCK_MONOTONIC, &now);
  return (int64_t)(now.tv_sec - start_time.tv_sec) * 1000 +
         (now.tv_nsec - start_time.tv_nsec) / 1000000;
}

static const struct options *g_opts;

/* Milliseconds left before --timeout-s; exits with 2 when none are left, and
 * with 3 when the parent process has gone (so that a crashed test never
 * leaves peers behind). */
static int64_t remaining_ms(void)
{
  int64_t left = g_opts->timeout_s * 1000 - elapsed_ms();
  if (getppid() != initial_ppid) {
    fprintf(stderr, "%s: parent process gone, exiting\n", prog);
    exit(EXIT_ORPHANED);
  }
  if (left <= 0) {
    emit("timeout");
    exit(EXIT_TIMEOUT);
  }
  return left;
}

static void sleep_ms(int64_t ms)
{
  while (ms > 0) {
    int64_t step = ms < 50 ? ms : 50;
    int64_t left = remaining_ms();
    if (step > left)
      step = left;
    dds_sleepfor(DDS_MSECS(step));
    ms -= step;
  }
  (void)remaining_ms();
}

/* ---- payload and output helpers ---- */

static uint8_t payload_byte(size_t i, uint32_t seq)
{
  return (uint8_t)((i * 7u + seq) & 0xffu);
}

static uint32_t fnv1a32(const uint8_t *p, size_t n)
{
  uint32_t h = 0x811c9dc5u;
  for (size_t i = 0; i < n; i++) {
    h ^= p[i];
    h *= 0x01000193u;
  }
  return h;
}

/* Text goes on one whitespace-free token: bytes outside 0x21..0x7e and the
 * characters % and " become %XX; the empty string is printed as "". */
static char *escape_text(const char *s)
{
  size_t n = strlen(s);
  char *out = malloc(n * 3 + 3);
  char *q = out;
  if (out == NULL)
    abort();
  if (n == 0) {
    strcpy(out, "\"\"");
    return out;
  }
  for (const unsigned char *p = (const unsigned char *)s; *p; p++) {
    if (*p <= 0x20 || *p >= 0x7f || *p == '%' || *p == '"') {
      sprintf(q, "%%%02X", *p);
      q += 3;
    } else {
      *q++ = (char)*p;
    }
  }
  *q = '\0';
  return out;
}

static void print_sample_msg(const courier_test_Msg *m)
{
  char *t = escape_text(m->text ? m->text : "");
  emit("sample %" PRIu32 " %s %" PRIu32 " %08" PRIx32, m->seq, t, m->payload._length,
      fnv1a32(m->payload._buffer, m->payload._length));
  free(t);
}

static void print_sample_strkeyed(const courier_test_StrKeyed *k)
{
  char *n = escape_text(k->name ? k->name : "");
  char *t = escape_text(k->text ? k->text : "");
  emit("sample %s %" PRIu32 " %s", n, k->seq, t);
  free(n);
  free(t);
}

static void print_sample_keyed(const courier_test_Keyed *k)
{
  char *t = escape_text(k->text ? k->text : "");
  emit("sample %" PRId32 " %" PRIu32 " %s", k->id, k->seq, t);
  free(t);
}

/* An instance of `stamped`: "<id>:<stamp>", at most 11 + 1 + 20 + 1 bytes. */
static void stamped_label(const courier_test_Stamped *k, char *buf, size_t cap)
{
  snprintf(buf, cap, "%" PRId32 ":%" PRId64, k->id, k->stamp);
}

static void print_sample_stamped(const courier_test_Stamped *k)
{
  char label[40];
  char *t = escape_text(k->text ? k->text : "");
  stamped_label(k, label, sizeof label);
  emit("sample %s %" PRIu32 " %s", label, k->seq, t);
  free(t);
}

/* ---- QoS ---- */

static dds_qos_t *make_qos(const struct options *o)
{
  static const dds_data_representation_id_t xcdr1[] = {DDS_DATA_REPRESENTATION_XCDR1};
  dds_qos_t *q = dds_create_qos();
  dds_history_kind_t hk = o->keep_all ? DDS_HISTORY_KEEP_ALL : DDS_HISTORY_KEEP_LAST;
  int32_t depth = o->keep_all ? 1 : (int32_t)o->depth;
  if (o->reliability == 1)
    dds_qset_reliability(q, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
  else
    dds_qset_reliability(q, DDS_RELIABILITY_BEST_EFFORT, 0);
  dds_qset_durability(q, o->transient_local ? DDS_DURABILITY_TRANSIENT_LOCAL : DDS_DURABILITY_VOLATILE);
  dds_qset_history(q, hk, depth);
  if (o->transient_local) /* what a late joiner gets: the same history */
    dds_qset_durability_service(q, 0, hk, depth, DDS_LENGTH_UNLIMITED, DDS_LENGTH_UNLIMITED,
        DDS_LENGTH_UNLIMITED);
  dds_qset_data_representation(q, 1, xcdr1);
  return q;
}

/* ---- status ---- */

static int32_t last_matched = 0;

static void check_matched(dds_entity_t ep, bool is_writer)
{
  int32_t cur;
  dds_return_t rc;
  if (is_writer) {
    dds_publication_matched_status_t st;
    rc = dds_get_publication_matched_status(ep, &st);
    cur = (int32_t)st.current_count;
  } else {
    dds_subscription_matched_status_t st;
    rc = dds_get_subscription_matched_status(ep, &st);
    cur = (int32_t)st.current_count;
  }
  if (rc != DDS_RETCODE_OK)
    fail("get matched status", rc);
  if (cur != last_matched) {
    last_matched = cur;
    emit("matched %" PRId32, cur);
  }
}

/* ---- publisher ---- */

/* --wait-stdin: waits for a line on standard input, the test's signal that
 * the subscriber has matched too (a writer matching a reader does not mean
 * the reader knows the writer yet). End of input before it is an error. */
static void wait_stdin_line(void)
{
  for (;;) {
    struct pollfd p = {.fd = STDIN_FILENO, .events = POLLIN};
    int64_t left = remaining_ms();
    int r = poll(&p, 1, left < 50 ? (int)left : 50);
    if (r < 0 && errno != EINTR) {
      fprintf(stderr, "%s: error: poll stdin: %s\n", prog, strerror(errno));
      exit(EXIT_RUNTIME);
    }
    if (r > 0) {
      char c;
      ssize_t n = read(STDIN_FILENO, &c, 1);
      if (n == 0) {
        fprintf(stderr, "%s: error: --wait-stdin: standard input ended before a line\n", prog);
        exit(EXIT_RUNTIME);
      }
      if (n < 0 && errno != EINTR && errno != EAGAIN) {
        fprintf(stderr, "%s: error: read stdin: %s\n", prog, strerror(errno));
        exit(EXIT_RUNTIME);
      }
      if (n == 1 && c == '\n')
        return;
    }
  }
}

static void fill_msg(courier_test_Msg *m, uint32_t seq, size_t size, const char *prefix, char *text,
    size_t textcap)
{
  snprintf(text, textcap, "%s-%" PRIu32, prefix, seq);
  m->seq = seq;
  m->text = text;
  for (size_t i = 0; i < size; i++)
    m->payload._buffer[i] = payload_byte(i, seq);
  m->payload._length = (uint32_t)size;
  m->payload._maximum = (uint32_t)size;
  m->payload._release = false;
}

static void write_retrying(dds_entity_t wr, const void *sample, const char *what)
{
  for (;;) {
    dds_return_t rc = dds_write(wr, sample);
    if (rc == DDS_RETCODE_OK)
      return;
    if (rc != DDS_RETCODE_TIMEOUT)
      fail(what, rc);
    (void)remaining_ms(); /* history full (keep-all): try again until --timeout-s */
  }
}

/* Writes keyed sample `k` (instance `id`), and disposes its instance every
 * --dispose-every writes. */
static void write_keyed(dds_entity_t wr, const void *k, int32_t id, uint32_t seq, long n,
                        const struct options *o)
{
  write_retrying(wr, k, "write");
  emit("sent %" PRId32 " %" PRIu32, id, seq);
  if (o->dispose_every && n % o->dispose_every == 0) {
    dds_return_t rc = dds_dispose(wr, k);
    if (rc != DDS_RETCODE_OK)
      fail("dispose", rc);
    emit("dispose %" PRId32, id);
  }
}

static void run_pub(const struct options *o, dds_entity_t wr, dds_entity_t ws)
{
  size_t maxsize = 0;
  uint8_t *buf;
  size_t textcap = strlen(o->text) + 16;
  char *text = malloc(textcap);
  for (int i = 0; i < o->nsizes; i++)
    if ((size_t)o->sizes[i] > maxsize)
      maxsize = (size_t)o->sizes[i];
  buf = malloc(maxsize ? maxsize : 1);
  if (buf == NULL || text == NULL)
    abort();

  if (o->wait_match > 0) {
    while (last_matched < o->wait_match) {
      int64_t left = remaining_ms();
      dds_waitset_wait(ws, NULL, 0, DDS_MSECS(left < 50 ? left : 50));
      check_matched(wr, true);
    }
  }
  if (o->wait_stdin)
    wait_stdin_line();
  if (o->wait_match > 0)
    sleep_ms(o->settle_ms);

  for (long n = 1; n <= o->count; n++) {
    uint32_t seq = (uint32_t)n;
    (void)remaining_ms();
    check_matched(wr, true);
    if (o->type == TYPE_MSG) {
      courier_test_Msg m;
      size_t size = (size_t)o->sizes[(n - 1) % o->nsizes];
      m.payload._buffer = buf;
      fill_msg(&m, seq, size, o->text, text, textcap);
      write_retrying(wr, &m, "write");
      emit("sent %" PRIu32, seq);
    } else if (o->type == TYPE_STAMPED) {
      courier_test_Stamped k;
      int32_t id = o->keys ? (int32_t)(n % o->keys) : (int32_t)n;
      snprintf(text, textcap, "%s-%" PRIu32, o->text, seq);
      k.id = id;
      k.stamp = STAMP_BASE + id;
      k.seq = seq;
      k.text = text;
      write_keyed(wr, &k, id, seq, n, o);
    } else {
      courier_test_Keyed k;
      int32_t id = o->keys ? (int32_t)(n % o->keys) : (int32_t)n;
      snprintf(text, textcap, "%s-%" PRIu32, o->text, seq);
      k.id = id;
      k.seq = seq;
      k.text = text;
      write_keyed(wr, &k, id, seq, n, o);
    }
    if (o->period_ms && n < o->count)
      sleep_ms(o->period_ms);
  }

  if (o->reliability == 1 && o->count > 0) {
    for (;;) {
      int64_t left = remaining_ms();
      dds_return_t rc = dds_wait_for_acks(wr, DDS_MSECS(left < 100 ? left : 100));
      if (rc == DDS_RETCODE_OK) {
        emit("acked");
        break;
      }
      if (rc != DDS_RETCODE_TIMEOUT)
        fail("wait for acks", rc);
      check_matched(wr, true);
    }
  }
  if (o->linger_ms) {
    int64_t until = elapsed_ms() + o->linger_ms;
    while (elapsed_ms() < until) {
      int64_t left = until - elapsed_ms();
      if (left > remaining_ms())
        left = remaining_ms();
      dds_waitset_wait(ws, NULL, 0, DDS_MSECS(left < 50 ? left : 50));
      check_matched(wr, true);
    }
  }
  emit("done");
  free(buf);
  free(text);
}

/* ---- subscriber ---- */

#define MAX_TRACKED 4096
struct inst_state {
  int32_t id;
  uint32_t state;
};
static struct inst_state tracked[MAX_TRACKED];
static size_t ntracked;

/* The names of the string keys seen, so that an instance of a string key
 * is tracked by a number like an int key. */
static char *names[MAX_TRACKED];
static size_t nnames;

static int32_t name_id(const char *name)
{
  for (size_t i = 0; i < nnames; i++)
    if (strcmp(names[i], name) == 0)
      return (int32_t)i;
  if (nnames == MAX_TRACKED)
    return (int32_t)(MAX_TRACKED - 1);
  names[nnames] = strdup(name);
  if (names[nnames] == NULL)
    fail("strdup", DDS_RETCODE_OUT_OF_RESOURCES);
  return (int32_t)nnames++;
}

/* Reports a disposed/unregistered instance once per transition out of ALIVE
 * (named `label` when given, else by `id`); returns true when it reported a
 * disposal. */
static bool track_instance(int32_t id, const char *label, dds_instance_state_t st)
{
  size_t i;
  for (i = 0; i < ntracked; i++)
    if (tracked[i].id == id)
      break;
  if (i == ntracked) {
    if (ntracked == MAX_TRACKED)
      i = ntracked - 1; /* reuse the last slot; tests never get near this */
    else
      ntracked++;
    tracked[i].id = id;
    tracked[i].state = DDS_IST_ALIVE;
  }
  if (st == tracked[i].state)
    return false;
  tracked[i].state = st;
  char num[16];
  if (label == NULL) {
    snprintf(num, sizeof num, "%" PRId32, id);
    label = num;
  }
  if (st == DDS_IST_NOT_ALIVE_DISPOSED) {
    emit("disposed %s", label);
    return true;
  }
  if (st == DDS_IST_NOT_ALIVE_NO_WRITERS)
    emit("unregistered %s", label);
  return false;
}

#define TAKE_BATCH 16

static void run_sub(const struct options *o, dds_entity_t rd, dds_entity_t ws)
{
  long received = 0, disposed = 0;
  void *samples[TAKE_BATCH];
  dds_sample_info_t infos[TAKE_BATCH];
  for (;;) {
    int64_t left = remaining_ms();
    dds_return_t n;
    check_matched(rd, false);
    memset(samples, 0, sizeof samples);
    n = dds_take(rd, samples, infos, TAKE_BATCH, TAKE_BATCH);
    if (n < 0)
      fail("take", n);
    for (int i = 0; i < n; i++) {
      if (o->type == TYPE_MSG) {
        if (infos[i].valid_data) {
          print_sample_msg(samples[i]);
          received++;
        }
      } else if (o->type == TYPE_KEYED) {
        const courier_test_Keyed *k = samples[i];
        if (infos[i].valid_data) {
          print_sample_keyed(k);
          received++;
        }
        if (track_instance(k->id, NULL, infos[i].instance_state))
          disposed++;
      } else if (o->type == TYPE_STAMPED) {
        /* an invalid sample (a dispose) holds the key fields only */
        const courier_test_Stamped *k = samples[i];
        char label[40];
        stamped_label(k, label, sizeof label);
        if (infos[i].valid_data) {
          print_sample_stamped(k);
          received++;
        }
        if (track_instance(name_id(label), label, infos[i].instance_state))
          disposed++;
      } else {
        /* an invalid sample (a dispose) holds the key fields only */
        const courier_test_StrKeyed *k = samples[i];
        const char *name = k->name ? k->name : "";
        char *label = escape_text(name);
        if (infos[i].valid_data) {
          print_sample_strkeyed(k);
          received++;
        }
        if (track_instance(name_id(name), label, infos[i].instance_state))
          disposed++;
        free(label);
      }
    }
    if (n > 0) {
      dds_return_t rc = dds_return_loan(rd, samples, n);
      if (rc != DDS_RETCODE_OK)
        fail("return loan", rc);
    }
    if ((o->count_set || o->disposed_set) && (!o->count_set || received >= o->count) &&
        (!o->disposed_set || disposed >= o->disposed))
      break;
    if (n == 0)
      dds_waitset_wait(ws, NULL, 0, DDS_MSECS(left < 50 ? left : 50));
  }
  /* Stay a while so that the writer sees this reader's acknowledgements
   * (Fast DDS 2.9 does not understand Cyclone's dispose of a leaving
   * endpoint and would otherwise wait for it until its lease expires). */
  if (o->linger_ms) {
    int64_t until = elapsed_ms() + o->linger_ms;
    while (elapsed_ms() < until) {
      int64_t left = until - elapsed_ms();
      sleep_ms(left < 50 ? left : 50); /* not the waitset: data may stay available */
      check_matched(rd, false);
    }
  }
  emit("done");
}

int main(int argc, char **argv)
{
  struct options o;
  dds_entity_t domain, pp, tp, ep, ws;
  dds_qos_t *qos;
  dds_return_t rc;
  char *config, *tracing = NULL;
  size_t cfglen;

  clock_gettime(CLOCK_MONOTONIC, &start_time);
  initial_ppid = getppid();
  parse_args(argc, argv, &o);
  g_opts = &o;
  setvbuf(stdout, NULL, _IOLBF, 0);

  /* Only the built-in loopback configuration is ever used. */
  if (getenv("CYCLONEDDS_URI") != NULL) {
    fprintf(stderr, "%s: ignoring CYCLONEDDS_URI, using the built-in loopback config\n", prog);
    unsetenv("CYCLONEDDS_URI");
  }
  if (o.trace) {
    const char *fmt = "<Tracing><Verbosity>finest</Verbosity><OutputFile>%s</OutputFile></Tracing>";
    tracing = malloc(strlen(fmt) + strlen(o.trace) + 1);
    if (tracing == NULL)
      abort();
    sprintf(tracing, fmt, o.trace);
  }
  cfglen = sizeof LOOPBACK_CONFIG + (tracing ? strlen(tracing) : 0) + sizeof KEYHASH_CONFIG;
  config = malloc(cfglen);
  if (config == NULL)
    abort();
  snprintf(config, cfglen, LOOPBACK_CONFIG, o.keyhash ? KEYHASH_CONFIG : "", tracing ? tracing : "");
  free(tracing);

  domain = dds_create_domain((dds_domainid_t)o.domain, config);
  if (domain < 0)
    fail("create domain with the loopback config", domain);
  free(config);
  pp = dds_create_participant((dds_domainid_t)o.domain, NULL, NULL);
  if (pp < 0)
    fail("create participant", pp);

  qos = make_qos(&o);
  tp = dds_create_topic(pp,
      o.type == TYPE_MSG       ? &courier_test_Msg_desc
      : o.type == TYPE_KEYED   ? &courier_test_Keyed_desc
      : o.type == TYPE_STAMPED ? &courier_test_Stamped_desc
                               : &courier_test_StrKeyed_desc,
      o.topic, qos, NULL);
  if (tp < 0)
    fail("create topic", tp);
  if (o.role == 1) {
    /* --no-autodispose: deleting the writer unregisters its instances
     * instead of disposing them */
    dds_qset_writer_data_lifecycle(qos, !o.no_autodispose);
    ep = dds_create_writer(pp, tp, qos, NULL);
  } else {
    ep = dds_create_reader(pp, tp, qos, NULL);
  }
  if (ep < 0)
    fail(o.role == 1 ? "create writer" : "create reader", ep);
  dds_delete_qos(qos);

  rc = dds_set_status_mask(ep, o.role == 1 ? DDS_PUBLICATION_MATCHED_STATUS
                                           : (DDS_SUBSCRIPTION_MATCHED_STATUS | DDS_DATA_AVAILABLE_STATUS));
  if (rc != DDS_RETCODE_OK)
    fail("set status mask", rc);
  ws = dds_create_waitset(pp);
  if (ws < 0)
    fail("create waitset", ws);
  rc = dds_waitset_attach(ws, ep, ep);
  if (rc != DDS_RETCODE_OK)
    fail("attach to waitset", rc);

  emit("ready");
  check_matched(ep, o.role == 1);
  if (o.role == 1)
    run_pub(&o, ep, ws);
  else
    run_sub(&o, ep, ws);

  rc = dds_delete(domain);
  if (rc != DDS_RETCODE_OK)
    fail("delete", rc);
  return 0;
}
