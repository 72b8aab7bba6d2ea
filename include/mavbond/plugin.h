/* mavbond filter plugin ABI: the only header a plugin needs (plain C, no yaml-cpp, no C++).
 *
 * A plugin is a shared object exporting MAVBOND_PLUGIN_ENTRY_SYMBOL, a function returning a
 * descriptor, and (ABI 5) two plain data symbols the host reads from the file before any of
 * the plugin's code runs: its ABI version and its name (MAVBOND_PLUGIN_DATA). The host refuses
 * a plugin whose abi_version differs from its own, whose struct_size is smaller than it knows,
 * whose name differs from its file name, or that lacks create/destroy. Plugins run on the
 * loop thread: they never block, never start threads, and use the host's timers and clock.
 *
 * Lifetimes: every pointer the host passes to a hook is valid only during that call, unless
 * said otherwise. Strings are NUL-terminated UTF-8.
 */
#ifndef MAVBOND_PLUGIN_H
#define MAVBOND_PLUGIN_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Bumped on every incompatible change; the host accepts exactly its own version. */
#define MAVBOND_PLUGIN_ABI_VERSION 5u  /* 2: the metrics hook; 3: stream positions, arrival
                                          * times, bond positions, bond members; 4: ingress
                                          * in batches, scope matched by the host, provides;
                                          * 5: the ABI version and name as data symbols,
                                          * MAVBOND_PROVIDES_ACTIVE_LINK, a link's endpoint, its
                                          * count markers' account,
                                          * the far side's resend, the describe hook */
#define MAVBOND_PLUGIN_ENTRY_SYMBOL "mavbond_plugin_entry"
/* ABI 5: a const uint32_t holding MAVBOND_PLUGIN_ABI_VERSION and a const char array holding
 * the plugin's name, both plain data (no relocation): the host reads them from the file, so a
 * plugin built for another ABI or under another name is refused without running any of it. */
#define MAVBOND_PLUGIN_ABI_SYMBOL "mavbond_plugin_abi_version"
#define MAVBOND_PLUGIN_NAME_SYMBOL "mavbond_plugin_name"

#define MAVBOND_EXPORT __attribute__((visibility("default")))

/* Defines the two data symbols; once per plugin, at file scope (MAVBOND_FILTER_PLUGIN does
 * it for C++ plugins). `name` is a string literal equal to the file name (NAME.so). */
#ifdef __cplusplus
#define MAVBOND_PLUGIN_DATA(name)                                                              \
    extern "C" MAVBOND_EXPORT const uint32_t mavbond_plugin_abi_version =                      \
        MAVBOND_PLUGIN_ABI_VERSION;                                                            \
    extern "C" MAVBOND_EXPORT const char mavbond_plugin_name[] = name
#else
#define MAVBOND_PLUGIN_DATA(name)                                                              \
    MAVBOND_EXPORT const uint32_t mavbond_plugin_abi_version = MAVBOND_PLUGIN_ABI_VERSION;     \
    MAVBOND_EXPORT const char mavbond_plugin_name[] = name
#endif

typedef enum mavbond_verdict {
    MAVBOND_PASS = 0, /* on to the next filter, then routing or sending */
    MAVBOND_DROP = 1  /* stop here; the host counts it against this filter */
} mavbond_verdict;

typedef enum mavbond_log_level {
    MAVBOND_LOG_ERROR = 3,
    MAVBOND_LOG_WARNING = 4,
    MAVBOND_LOG_NOTICE = 5,
    MAVBOND_LOG_INFO = 6,
    MAVBOND_LOG_DEBUG = 7
} mavbond_log_level;

/* A frame whose framing and CRC the host has checked (crc_checked 0: unknown msgid). */
typedef struct mavbond_frame {
    uint32_t struct_size;
    uint8_t version;          /* 1 or 2 */
    uint8_t incompat_flags;   /* 0x01: signed */
    uint8_t seq;
    uint8_t sysid;
    uint8_t compid;
    uint8_t crc_checked;
    int16_t target_system;    /* -1: the message has no such field */
    int16_t target_component; /* -1: the message has no such field */
    uint32_t msgid;
    const uint8_t *raw;       /* the whole frame as on the wire */
    uint32_t raw_len;
    const uint8_t *payload;   /* the payload as on the wire (v2: possibly truncated) */
    uint32_t payload_len;
    int16_t timestamp_offset; /* wire offset of time_boot_ms / time_usec in the payload, -1: none */
    uint8_t timestamp_size;   /* its size in bytes, 4 or 8; 0: none */
    uint8_t timestamp_us;     /* 1: microseconds (time_usec), 0: milliseconds (time_boot_ms) */
    /* When the frame arrived, CLOCK_MONOTONIC: the kernel's receive time of its datagram (UDP),
     * the time of the read that completed it (UART, TCP). Never when the loop got to it: the
     * frames of a bond's links reach the filters in this order, a stalled daemon included. */
    uint64_t rx_time_ns;
    /* ABI 3: the frame's place in its source's (sysid, compid) stream on the link it came
     * from, as the host tracks it for every link: the sequence byte unwrapped (the first frame
     * of a source is at its seq, 0..255; a step of 1..127 forward moves on, a step back is a
     * late frame). Links number their copies each their own way: positions of two links are
     * comparable only once aligned (dedup does, and notes the bond's numbering). */
    int64_t stream_pos;
    int32_t stream_lost;      /* frames of the source this link skipped before this one (a gap);
                               * -1: this late frame fills a gap counted before; 0 otherwise */
    uint32_t stream_flags;    /* MAVBOND_STREAM_* */
} mavbond_frame;

/* stream_flags */
#define MAVBOND_STREAM_REPEAT 0x1u    /* a position this link already had (or too far back to
                                       * tell): not a new frame of the source on this link */
#define MAVBOND_STREAM_RESYNC 0x2u    /* the numbering restarted here (a run of frames that fit
                                       * no gap: a rebooted sender): positions before and after
                                       * are not comparable */
#define MAVBOND_STREAM_UNTRACKED 0x4u /* more sources than the host tracks on this link:
                                       * stream_pos is the bare sequence byte */

/* Filled by filters for the ones after them in the chain (one per frame, zeroed at ingress). */
typedef struct mavbond_frame_notes {
    uint32_t struct_size;
    uint32_t flags;           /* MAVBOND_NOTE_* */
    uint64_t hash[2];         /* the frame's key hash, when MAVBOND_NOTE_HASHED */
    uint32_t first_link_id;   /* MAVBOND_NOTE_DUPLICATE: the link the first copy came on */
    int64_t skew_ns;          /* MAVBOND_NOTE_DUPLICATE: this copy's arrival minus the first's */
    int64_t bond_pos;         /* MAVBOND_NOTE_POSITION (ABI 3): the frame's position in its
                               * source's stream as the bond numbers it, every link aligned
                               * to one numbering (copies of one frame share it) */
} mavbond_frame_notes;

#define MAVBOND_NOTE_HASHED 0x1u
#define MAVBOND_NOTE_DUPLICATE 0x2u /* a copy of a frame already delivered from another link */
#define MAVBOND_NOTE_STALE 0x4u     /* older than a sample already delivered */
/* An earlier filter dropped the frame. The host still shows it to the filters after that one
 * (observers such as stats count it) and ignores their verdicts; a filter that keeps state
 * (dedup) must not learn from it, so a frame dropped for another reason never shadows its
 * good copy. */
#define MAVBOND_NOTE_DROPPED 0x8u
#define MAVBOND_NOTE_POSITION 0x10u /* bond_pos is set */

#define MAVBOND_NO_BOND UINT32_MAX

/* What an instance declares it does for the bonds in its scope (ABI 4: host_api.provides). */
#define MAVBOND_PROVIDES_ALIGNED_POSITIONS 0x1u /* notes MAVBOND_NOTE_POSITION on the frames it
                                                 * places, one numbering for links that number
                                                 * the stream each their own way: the bond may
                                                 * renumber (`renumber: true`) */
#define MAVBOND_PROVIDES_ACTIVE_LINK 0x2u       /* (ABI 5) chooses the bonds' active link
                                                 * (set_active_link): a `tx: active` bond
                                                 * needs it, or it would send on every link */

/* A link (route target) as plugins see it. Ids are dense and stable while it exists. */
typedef struct mavbond_link {
    uint32_t struct_size;
    uint32_t id;
    const char *name;         /* "radio", or "gcs@127.0.0.1:5555" for a learned UDP peer */
    uint32_t bond_id;         /* MAVBOND_NO_BOND when not in a bond */
    const char *bond_name;    /* NULL when not in a bond */
    uint32_t priority;        /* position of the link among its bond's members (0 first) */
    const char *endpoint;     /* ABI 5: the configured endpoint it belongs to ("gcs" for
                               * "gcs@127.0.0.1:5555"): a name that stays when a peer's address
                               * changes (a NAT's new port), for metric labels */
} mavbond_link;

/* ABI 4: one frame of an ingress batch, as a filter gets it. */
typedef struct mavbond_received {
    const mavbond_frame *frame;
    mavbond_frame_notes *notes;   /* what the filters before this one noted */
    const mavbond_link *from;
    mavbond_verdict verdict;      /* the filter's answer: the host sets MAVBOND_PASS before the
                                   * call, a filter that drops the frame writes MAVBOND_DROP */
} mavbond_received;

/* The host's own counters of a link (parsing and transmit), for observers such as stats. */
typedef struct mavbond_link_counters {
    uint32_t struct_size;
    uint64_t rx_frames;
    uint64_t rx_bytes;
    uint64_t crc_errors;
    uint64_t garbage_bytes;
    uint64_t unknown_ids;
    uint64_t tx_frames;
    uint64_t tx_bytes;
    uint64_t tx_dropped;
    /* ABI 5: what the far side wrote on the link, by the count markers a far mavbond sends
     * (unlike sequence gaps, frames it chose not to send there are not loss): */
    uint32_t account_flags;   /* MAVBOND_ACCOUNT_*; the two counts are 0 without EXACT */
    uint64_t account_expected;  /* frames the far side wrote on the link: what its markers said,
                                 * and every frame that came in since the last one (its loss, if
                                 * any, is told by the next marker) */
    uint64_t account_received;  /* of them, the ones that arrived (both only grow) */
} mavbond_link_counters;

#define MAVBOND_ACCOUNT_EXACT 0x1u        /* the far side counts: the figures are exact */
#define MAVBOND_ACCOUNT_PEER_STANDBY 0x2u /* its last marker: it keeps the link in standby */
#define MAVBOND_ACCOUNT_MOVED 0x4u        /* another link goes on with this account (a UDP peer
                                           * a NAT moved): its figures are that link's too */

typedef struct mavbond_bond_state {
    uint32_t struct_size;
    uint32_t active_link_id;  /* UINT32_MAX: none chosen (every member sends, `tx: broadcast`) */
    uint64_t switches;        /* changes of the active link since start */
    uint8_t tx_active;        /* 1: `tx: active`, 0: `tx: broadcast` */
    /* ABI 5: how far back the bond's far side resends, on its failover, what its standby kept
     * off its metered members (its `resend`, as it announced it over the bond; until it has,
     * this side's own): the resent copies come that much later than the frames' first copies,
     * plus the links' skew. 0: no resend (no metered member). */
    uint64_t peer_resend_ns;
    uint8_t peer_resend_announced; /* 1: peer_resend_ns is what the far side said */
} mavbond_bond_state;

typedef enum mavbond_link_event {
    MAVBOND_LINK_ADDED = 0,
    MAVBOND_LINK_REMOVED = 1
} mavbond_link_event;

/* Option types a plugin declares; the host validates the YAML against them before create. */
typedef enum mavbond_option_type {
    MAVBOND_OPT_BOOL = 1,
    MAVBOND_OPT_INT = 2,      /* 64-bit signed */
    MAVBOND_OPT_DURATION = 3, /* "250ms", "2s": read as nanoseconds */
    MAVBOND_OPT_PERCENT = 4,  /* "5%": read as a fraction (0.05) */
    MAVBOND_OPT_STRING = 5,
    MAVBOND_OPT_STRINGS = 6   /* a YAML sequence of strings */
} mavbond_option_type;

typedef struct mavbond_option {
    const char *key;
    mavbond_option_type type;
    const char *default_value; /* YAML text; NULL: no default (absent unless given) */
    const char *help;
} mavbond_option;

/* Metrics (ABI 2): a plugin's figures as typed samples for the daemon's Prometheus endpoint.
 * The host names a sample mavbond_PLUGIN_NAME (plus _total for a counter), adds the label
 * filter="INSTANCE" and groups samples by name. NAME: [a-zA-Z0-9_]; label names: [a-zA-Z_]
 * then [a-zA-Z0-9_], not "filter", at most MAVBOND_METRIC_MAX_LABELS; label values: any
 * UTF-8. Samples of one name must agree on type and help; the host skips (and logs once)
 * any sample that breaks a rule. */
typedef enum mavbond_metric_type {
    MAVBOND_METRIC_COUNTER = 1, /* only grows (from 0 at the instance's creation): `count` */
    MAVBOND_METRIC_GAUGE = 2    /* any value, NaN and infinities included: `value` */
} mavbond_metric_type;

#define MAVBOND_METRIC_MAX_LABELS 8

typedef struct mavbond_label {
    const char *name;
    const char *value;
} mavbond_label;

typedef struct mavbond_metric_sample {
    uint32_t struct_size;
    mavbond_metric_type type;
    const char *name;
    const char *help;
    const mavbond_label *labels;
    uint32_t label_count;
    uint64_t count;           /* COUNTER: exact, never a float */
    double value;             /* GAUGE */
} mavbond_metric_sample;

/* The host's callback for one sample; every pointer in it is read during the call only. */
typedef void (*mavbond_metric_sink)(void *sink_ctx, const mavbond_metric_sample *sample);

typedef struct mavbond_host mavbond_host;     /* opaque: one per filter instance */
typedef struct mavbond_config mavbond_config; /* opaque: this instance's options */

typedef struct mavbond_host_api {
    uint32_t struct_size;
    /* Logs one line, prefixed by the host with "[filter:NAME]". */
    void (*log)(mavbond_host *h, mavbond_log_level level, const char *message);
    /* The monotonic clock in nanoseconds, as far as arrivals go: every frame that arrived
     * before it has been shown to the filters (cached per loop round; after a stall it trails
     * the wall while the backlog is worked off, so a timer never takes a stall for silence). */
    uint64_t (*now_ns)(mavbond_host *h);
    /* Calls cb(user) every period_ns until it returns 0 or the timer is cancelled.
     * Returns 0 and a timer id, or -errno. */
    int (*timer_add)(mavbond_host *h, uint64_t period_ns, int (*cb)(void *user), void *user,
                     uint64_t *out_id);
    void (*timer_cancel)(mavbond_host *h, uint64_t id);
    /* The links in this instance's scope now, in id order: fills up to max, returns how
     * many there are. (ABI 4: only those in scope, as on_link and on_ingress see them.) */
    size_t (*links)(mavbond_host *h, const mavbond_link **out, size_t max);
    /* The id of a bond by name, or -ENOENT. */
    int (*bond_by_name)(mavbond_host *h, const char *name, uint32_t *out_bond_id);
    /* Makes link_id the bond's active link (for `tx: active` bonds). -EINVAL if not a member. */
    int (*set_active_link)(mavbond_host *h, uint32_t bond_id, uint32_t link_id);
    /* The host's counters of a link, or -ENOENT. */
    int (*link_counters)(mavbond_host *h, uint32_t link_id, mavbond_link_counters *out);
    /* A bond's active link and switch count, or -ENOENT. */
    int (*bond_state)(mavbond_host *h, uint32_t bond_id, mavbond_bond_state *out);

    /* Typed option values (defaults applied by the host). 0, or -ENOENT when absent. */
    int (*cfg_bool)(const mavbond_config *c, const char *key, int *out);
    int (*cfg_int)(const mavbond_config *c, const char *key, int64_t *out);
    int (*cfg_duration_ns)(const mavbond_config *c, const char *key, uint64_t *out);
    int (*cfg_percent)(const mavbond_config *c, const char *key, double *out);
    int (*cfg_string)(const mavbond_config *c, const char *key, const char **out);
    /* out is valid for the instance's life. */
    int (*cfg_strings)(const mavbond_config *c, const char *key, const char *const **out,
                       size_t *count);
    /* Writes "file:line:column: filter 'NAME': option 'KEY': MESSAGE" into err (for create). */
    void (*cfg_error)(const mavbond_config *c, const char *key, const char *message, char *err,
                      size_t err_len);
    /* The bonds (names) and endpoints (names) this instance is scoped to; NULL/0: everywhere.
     * The host matches links against them itself: a plugin reads them only to check names
     * in its options at create. */
    void (*scope)(const mavbond_config *c, const char *const **bonds, size_t *bond_count,
                  const char *const **endpoints, size_t *endpoint_count);
    /* ABI 3: the endpoints the config puts in bond `bond`, in config order (their links'
     * priority), valid for the instance's life; -ENOENT when there is no such bond. For
     * checking names in options at create, before any link exists. */
    int (*cfg_bond_members)(const mavbond_config *c, const char *bond, const char *const **names,
                            size_t *count);
    /* ABI 3: the names of every bond the config declares, in config order (valid for the
     * instance's life). */
    void (*cfg_bonds)(const mavbond_config *c, const char *const **names, size_t *count);
    /* ABI 3: as cfg_error, at item `index` of a list option (the item's own line:column). */
    void (*cfg_item_error)(const mavbond_config *c, const char *key, size_t index,
                           const char *message, char *err, size_t err_len);
    /* ABI 4: declares, during create, what the instance does for the bonds in its scope
     * (MAVBOND_PROVIDES_*): the host checks a bond's needs against it. */
    void (*provides)(mavbond_host *h, uint32_t what);
} mavbond_host_api;

typedef struct mavbond_plugin_descriptor {
    uint32_t abi_version;           /* MAVBOND_PLUGIN_ABI_VERSION at build time */
    uint32_t struct_size;           /* sizeof(mavbond_plugin_descriptor) at build time */
    const char *name;               /* equals the file name (NAME.so) and the YAML `plugin:` */
    const char *version;
    const char *description;
    const mavbond_option *options;  /* terminated by an entry with key NULL */
    /* Builds an instance. Returns 0 and *out_self, or non-zero with a message in err.
     * The api and h pointers stay valid for the instance's life. */
    int (*create)(const mavbond_host_api *api, mavbond_host *h, const mavbond_config *cfg,
                  void **out_self, char *err, size_t err_len);
    void (*destroy)(void *self);
    /* Every frame received on a link in scope, after CRC checks, before routing: the frames
     * of one receive round in arrival order, `count` at a time. May be NULL. (ABI 4) */
    void (*on_ingress)(void *self, mavbond_received *frames, size_t count);
    /* Every (frame, destination link in scope) before the frame is queued. May be NULL. */
    mavbond_verdict (*on_egress)(void *self, const mavbond_frame *f, const mavbond_link *to);
    /* Links come and go (TCP clients, UDP peers). May be NULL. */
    void (*on_link)(void *self, const mavbond_link *link, mavbond_link_event event);
    /* Writes a JSON object describing the instance's state into buf (for the status socket);
     * returns the length it needed. May be NULL. */
    size_t (*status_json)(void *self, char *buf, size_t len);
    /* Calls sink(sink_ctx, &sample) once per sample (for a scrape of the metrics endpoint).
     * May be NULL. (ABI 2) */
    void (*metrics)(void *self, mavbond_metric_sink sink, void *sink_ctx);
    /* ABI 5: one line of plain text on what the instance derived for bond `bond_id` (a setting
     * that depends on others, and why), for the daemon's account of each bond at start and
     * reload; returns the length it needed (0: nothing to say). May be NULL. */
    size_t (*describe)(void *self, uint32_t bond_id, char *buf, size_t len);
} mavbond_plugin_descriptor;

typedef const mavbond_plugin_descriptor *(*mavbond_plugin_entry_fn)(void);

#ifdef __cplusplus
}
#endif

#endif /* MAVBOND_PLUGIN_H */
