/* dual_channel.pml: SPIN model of the two channels' protocol of one producer node and one
 * consumer node (EN 50325-5 Annex A.4, Model III; CiA 304 9.5), mirroring
 * dual-channel/src/runtime.rs, channel-a/src/role.rs and channel-b/src/role.rs.
 * dual-channel/model/README.md maps every process and step to the Rust it mirrors, says how
 * time is scaled and lists the properties and the mutation switches.
 */

/* ---------------------------------------------------------------------------------------
 * Mirrored constants: the real values, in microseconds or slots, as the Rust has them.
 * dual-channel/tests/model_mirror.rs reads these lines and fails when one differs from Rust.
 * ------------------------------------------------------------------------------------- */
#define SAMPLE_WINDOW_US       5000    /* dual_channel::runtime::SAMPLE_WINDOW */
#define INPUT_DISCREPANCY_US   200000  /* dual_channel::runtime::INPUT_DISCREPANCY */
#define LINK_PERIOD_US         10000   /* board::hw::LINK_PERIOD */
#define LINK_TIMEOUT_FACTOR    2       /* Runtime::around: timeout = 2 * link_period */
#define REFRESH_US             25000   /* SafetyConfig::predefined, producer refresh time */
#define SCT_US                 50000   /* SafetyConfig::predefined, consumer SCT */
#define SRVT_US                20000   /* SafetyConfig::predefined, consumer SRVT */
#define PRODUCER_START_US      500     /* srdo::Producer::start, 0.5 ms x node-ID 1 */
#define VERDICT_DEPTH          4       /* dual_channel::crosscheck::DEPTH */
#define ANNOUNCED_SLOTS        4       /* channel_b::role::ChannelB::announced, FrameSlots<4> */
#define EARLY_SLOTS            4       /* Runtime::early, heapless::Vec<_, 4> */
#define AWAITED_SLOTS          8       /* channel_a::role::ChannelA::awaiting, [_; 8] */

/* ---------------------------------------------------------------------------------------
 * Model bounds (override with -D): time scale, link latencies, what the environment may do.
 * ------------------------------------------------------------------------------------- */
#ifndef TICK_US
#define TICK_US 5000            /* one tick of model time */
#endif
#ifndef P_LATENCY_T
#define P_LATENCY_T 0           /* producer link: tick boundaries a message may cross */
#endif
#ifndef C_LATENCY_T
#define C_LATENCY_T 1           /* consumer link: tick boundaries a message may cross */
#endif
#ifndef CONTACT_GAP_T
#define CONTACT_GAP_T 0         /* fault-free: tick boundaries between the two contacts */
#endif
#ifndef NMT_BUDGET
#define NMT_BUDGET 3            /* NMT commands (start, reset) after power-on */
#endif
#ifndef INPUT_BUDGET
#define INPUT_BUDGET 2          /* input changes (both contacts) */
#endif
#ifndef FAULT_BUDGET
#define FAULT_BUDGET 1          /* injected faults, of the classes FAULTS enables */
#endif
#ifndef FAULTS
#define FAULTS 7                /* 1: foreign frame, 2: frame or link message lost, 4: stuck contact */
#endif
#define FOREIGN_FAULTS ((FAULTS / 1) % 2 == 1)
#define LOSS_FAULTS    ((FAULTS / 2) % 2 == 1)
#define STUCK_FAULTS   ((FAULTS / 4) % 2 == 1)
#ifndef DISC_CAP_T
#define DISC_CAP_T 6            /* input discrepancy, capped (see README) */
#endif
#ifndef SCT_CAP_T
#define SCT_CAP_T 12            /* SCT, capped (see README) */
#endif
#ifndef STARTED
#define STARTED 1               /* the master's first NMT start is queued at power-on */
#endif
#ifndef INITIAL_INPUT
#define INITIAL_INPUT 1         /* both contacts at power-on (1: closed, the outputs may run) */
#endif
#ifndef START_AFTER_RESET_T
#define START_AFTER_RESET_T 0   /* ticks the NMT master waits after a reset before a start */
#endif
/* -DRESET_NOT_OVERTAKING: the master's NMT commands never reach the bus while channel A's
 * plain frame waits in its transmit queue (such a frame reaches the bus after the reset: the
 * reset trails of docs/model-checking.md, fixed in channel B, and the two findings after
 * them there with an input change, fixed too): the master queues none then, and one it
 * queued before waits. */
#ifdef RESET_NOT_OVERTAKING
#define MASTER_MAY_SEND empty(tx_a)
#define M_READY (nempty(tx_m) && empty(tx_a))   /* the master's frame goes on the bus */
#define M_WAITS (empty(tx_m) || nempty(tx_a))   /* ... or not (SPIN negates no queue test) */
#else
#define MASTER_MAY_SEND true
#define M_READY nempty(tx_m)
#define M_WAITS empty(tx_m)
#endif
#ifndef SLOW_LOOPS
#define SLOW_LOOPS 0            /* channels (bit c) whose bus frames may lag their link */
#endif
#ifndef LATE_LOOPS
#define LATE_LOOPS 0            /* channels (bit c) whose bus frames may also wait a tick boundary */
#endif
#ifndef PAIR_MOD
#define PAIR_MOD 4              /* pair numbers are counted modulo this */
#endif

#define TICKS(us) (((us) + TICK_US - 1) / TICK_US)
#define W_T       TICKS(SAMPLE_WINDOW_US)
#define PERIOD_T  TICKS(LINK_PERIOD_US)
#define TIMEOUT_T TICKS(LINK_TIMEOUT_FACTOR * LINK_PERIOD_US)
#define REFRESH_T TICKS(REFRESH_US)
#define SRVT_T    TICKS(SRVT_US)
#if TICKS(INPUT_DISCREPANCY_US) > DISC_CAP_T
#define DISC_T    DISC_CAP_T
#else
#define DISC_T    TICKS(INPUT_DISCREPANCY_US)
#endif
#if TICKS(SCT_US) > SCT_CAP_T
#define SCT_T     SCT_CAP_T
#else
#define SCT_T     TICKS(SCT_US)
#endif

#define NONE 255

/* The four channels: producer A and B (node 1), consumer A and B (node 33). */
#define PA 0
#define PB 1
#define CA 2
#define CB 3
#define PEER(c) ((c) ^ 1)

/* NMT states (the model's; Initialising is passed through within one step). */
#define PREOP 0
#define OPER  1

/* CAN frames: identifier (in arbitration order), ghost sender, ghost announcement number,
 * one data bit. The inverted frame carries the data bit it is the inverse of. */
#define ID_START 0   /* NMT start (identifier 000h) */
#define ID_RESET 1   /* NMT reset communication (identifier 000h) */
#define ID_GFC   2   /* GFC (identifier 001h) */
#define ID_PLAIN 3   /* SRDO 1 plain frame, COB-ID 1 (101h) */
#define ID_INV   4   /* SRDO 1 inverted frame, COB-ID 2 (102h) */
#define S_A 0
#define S_B 1
#define S_X 2        /* a foreign sender */
#define S_M 3        /* the NMT master */
#define FRAME(id, src, num, d) ((id) * 32 + (src) * 8 + (num) * 2 + (d))
#define FID(f)   ((f) / 32)
#define FSRC(f)  (((f) / 8) % 4)
#define FNUM(f)  (((f) / 2) % 4)
#define FDATA(f) ((f) % 2)
/* FRAME(ID_RESET, S_M, 0, 0), as a literal: a channel poll takes constants only. */
#define RESET_FRAME 56
#define IS_SRDO(f) (FID(f) == ID_PLAIN || FID(f) == ID_INV)

/* Link messages: type and payload. */
#define M_HB       0 /* Heartbeat: oper * 8 + epoch * 2 + inputs */
#define M_INPUTS   1 /* Inputs: the sample */
#define M_VERDICT  2 /* Verdict: pair * 2 + data */
#define M_PLAIN    3 /* PlainFrame: ghost number * 2 + data */
#define M_SAFE     4 /* SafeState */
#define M_FOREIGN  5 /* ForeignFrame */
#define M_MISMATCH 6 /* TransmitMismatch */
#define MSG(t, p) ((t) * 32 + (p))
#define MTYPE(m) ((m) / 32)
#define MPAY(m)  ((m) % 32)

/* Why a channel latched (dual_channel::runtime::ChannelFault), and the core's own causes. */
#define F_LINK      1
#define F_CROSS     2
#define F_TRANSMIT  3
#define F_INVERTED  4
#define F_FOREIGN   5
#define F_NMT       6
#define F_INPUT     7
#define F_PEER      8
#define F_SRDO      9   /* the core: SCT, SRVT, plain repeated, not inverted */
#define F_GFC       10  /* the core: GFC received */

/* ---- Channel state (index: channel) ---- */
byte nmt[4];              /* PREOP / OPER */
byte epoch[4];            /* NmtCheck::epoch, modulo 4 */
byte peer_epoch[4];       /* NmtCheck::peer epoch (NONE: no heartbeat yet) */
byte peer_nmt[4];
byte nmt_cd[4];           /* NmtCheck: ticks until the mismatch is a fault */
byte fault[4];            /* Runtime::fault */
bool core_safe[4];        /* the core's safe state */
bool lost[4];             /* a link message to this channel was lost (sequence gap) */
bool cfg_ok[4];           /* ConfigurationCheck::confirmed */

/* Producer inputs (index: PA, PB). */
bool pin[2];              /* the contacts */
bool sampled[2];          /* the sample the runtime holds (set_input) */
byte peer_in[2];          /* InputCheck::peer */
byte dage[2];             /* InputCheck::differ_since as an age in ticks (NONE: agree) */
byte early[2];            /* Runtime::early: one SRDO frame seen before Operational */
byte early_cd[2];

/* Producer channel A: runtime, core, role. */
byte waiting = NONE;      /* Runtime::waiting */
byte handed = NONE;       /* Runtime::handed_on */
bool changed;             /* srdo::Producer::changed */
byte refresh_cd = NONE;   /* srdo::Producer::next as ticks */
byte awaited = NONE;      /* ChannelA::awaiting (frame) */
byte awaited_cd = NONE;
byte deferred = NONE;     /* ChannelA::deferred */
byte cut = NONE;          /* ChannelA::cut */
byte cut_cd = NONE;
byte ann_num;             /* ghost: announcements made, modulo 2 */

/* Producer channel B: role. */
byte held = NONE;         /* ChannelB::held (frame) */
byte held_cd = NONE;
byte unann = NONE;        /* ChannelB::unannounced (frame) */
byte unann_cd = NONE;
byte announced = NONE;    /* ChannelB::announced (frame, SRDO 1's slot) */
byte ended = NONE;        /* ChannelB::ended (A's announcement of its ended epoch, SRDO 1's slot) */
byte ended_cd = NONE;     /* ChannelB::ended_until: at least a window (W_T + 1 ticks) */
byte ended_unann = NONE;  /* ChannelB::ended_unannounced (frame seen before B's own reset) */
byte ended_unann_cd = NONE;
byte b_lead = 1;          /* ChannelB::epoch_lead + 1: 2 between B's reset and A's heartbeat */
byte prev = NONE;         /* ChannelB::previous (sample) */
byte gseen_ep;            /* ghost: B's epoch when it saw the frame being co-signed */
byte held_ep;             /* ghost: ... for the held frame */
byte unann_ep;            /* ghost: ... for the unannounced frame */
byte prev_age;            /* ticks since it was replaced, saturating at W_T */

/* Consumer channels (index: c - CA): core, runtime, verdict check. */
byte pend[2];             /* srdo consumer: pending plain frame */
byte srvt_cd[2];
byte sct_cd[2];
byte pairs[2];            /* Runtime::pairs */
byte peer_pairs[2];       /* Runtime::peer_pairs */
byte outp[2];             /* Runtime::outputs */
chan vloc[2] = [VERDICT_DEPTH] of { byte, byte };  /* VerdictCheck: local (pair*2+data, ticks left) */
chan vrem[2] = [VERDICT_DEPTH] of { byte, byte };  /* VerdictCheck: remote */

/* ---- Media ---- */
chan rx[4] = [4] of { byte };             /* each channel's receive queue */
chan link[4] = [6] of { byte, byte };     /* link to channel c: message, ticks left */
chan tx_a = [2] of { byte };              /* PA's transmit queue (plain frames) */
byte gfc_pending;                         /* PA's GFC requests not yet on the bus */
chan tx_b = [2] of { byte };              /* PB's transmit queue (inverted frames) */
chan tx_m = [2] of { byte };              /* the NMT master's queue */
byte foreign_frame = NONE;                /* a foreign sender's frame, waiting for the bus */

/* ---- Environment ---- */
byte nmt_left = NMT_BUDGET;
byte input_left = INPUT_BUDGET;
byte fault_left = FAULT_BUDGET;
bool injected;            /* a fault was injected in this run */
bool bus_drop;            /* the next frame on the bus is lost */
bool link_drop[4];        /* the next link message from channel c is lost */
byte gap_cd = NONE;       /* the second contact must follow within this many ticks */
bool env_done;            /* the environment made its last move (liveness) */
bool again;               /* a channel entered a safe state after the master's last move */
bool start_due;           /* the master's start follows its reset (liveness) */
byte restart_cd = NONE;   /* ticks until the master may restart the network (liveness) */
byte reset_age = 255;     /* ticks since the master's last reset, saturating */
bool env_turn = 1;        /* the environment moves at the start of each tick, first */

/* ---- Ghosts for the properties ---- */
byte gnew[2];             /* newest pair the consumer channel's core accepted: data */
bool gnew_genuine[2];     /* ... made of channel A's plain frame and channel B's inverted */
byte gpeer_pair[2] = NONE;/* the last verdict received from the other channel */
byte gpeer_data[2];
bool gfc_sent;            /* a GFC was on the bus */
byte foreign_cd = NONE;   /* ticks left for the node to reach the safe state */
bool got_pair[2];         /* a pair was confirmed since the last NMT reset */
bool paired[2];           /* srdo::Consumer::paired: the core took a pair since its start */
byte rx_late[4];          /* frames at the head of rx[c] that came before the last tick */
hidden int tick_count;           /* ticks since power-on, for the printed trail only */

/* The channel loop hands the runtime its bus frames before its link bytes, its pins and its
 * deadlines (ChannelLoop::service); a slow loop (SLOW_LOOPS) may take them in any order. */
#define LAGS(c) (((SLOW_LOOPS | LATE_LOOPS) / (1 << (c))) % 2 == 1)
/* A late loop (LATE_LOOPS) may also leave bus frames in its receive queue across one tick
 * boundary, as a receive delay of less than a tick does (the host simulation's): the other
 * channel's link messages sent after the boundary (its first announcement once its start
 * delay passed, say) may come before them. The delay shifts the channel's own deadlines with
 * its frames (they count from when it handled them), so it polls them only once the frames
 * of the last tick are handled. */
#define LATE(c) ((LATE_LOOPS / (1 << (c))) % 2 == 1)
#define RX_DONE(c) (empty(rx[c]) || (LATE(c) && rx_late[c] == 0))
#define WORKING(c) (fault[c] == 0 && !core_safe[c] && nmt[c] == OPER)
#define SAME_EPOCH(c) (peer_epoch[c] == NONE || peer_epoch[c] == epoch[c])
#define DEC(x) if :: (x) != NONE && (x) > 0 -> x = (x) - 1 :: else -> skip fi

/* ======================================================================================
 * Link (dual_channel::link): Sender::encode + the other channel's Receiver.
 * ==================================================================================== */
inline send_link(c, t, p) {
  if
  :: link_drop[c] -> link_drop[c] = 0; lost[PEER(c)] = 1;
     printf("@%d ch%d: link message %d lost\n", tick_count, c, t)
  :: else ->
     assert(nfull(link[PEER(c)]));   /* model bound: the link queue */
     if
     :: c < CA -> link[PEER(c)]!MSG(t, p), P_LATENCY_T
     :: else -> link[PEER(c)]!MSG(t, p), C_LATENCY_T
     fi
  fi
}

/* Runtime::heartbeat */
/* Runtime::heartbeat, sent at once on every NMT state change. The periodic heartbeats
 * repeat what the last one said (the NMT state and epoch, and the input digest that every
 * change sends at once as Message::Inputs), so the model leaves them out with the link's
 * time-out they feed (see README). */
inline heartbeat(c) {
  if
  :: c < CA -> send_link(c, M_HB, (nmt[c] == OPER -> 8 : 0) + epoch[c] * 2 + sampled[c])
  :: else -> send_link(c, M_HB, (nmt[c] == OPER -> 8 : 0) + epoch[c] * 2)
  fi
}

/* ======================================================================================
 * Latch (Runtime::latch, latch_holding) and the core's safe state.
 * ==================================================================================== */
inline clear_outputs(c) {
  if :: c >= CA -> outp[c - CA] = 0 :: else -> skip fi
}

inline safe_state_entered(c, why) {
  /* Availability: a fault-free run never reaches a safe state. */
  if
  :: !injected -> printf("@%d PROPERTY availability: ch%d safe, cause %d, no fault\n", tick_count, c, why)
  :: else -> skip
  fi;
  assert(injected);
#ifdef LIVENESS
  again = (again || (env_done && !core_safe[c] && (fault[c] == 0 || fault[c] == why)));
#endif
  core_safe[c] = 1
}

inline latch(c, why) {
  if
  :: fault[c] == 0 ->
     printf("@%d ch%d: LATCH cause %d\n", tick_count, c, why);
     fault[c] = why;
     if :: c == PA -> waiting = NONE :: else -> skip fi;
     clear_outputs(c);
     if :: why != F_PEER -> send_link(c, M_SAFE, 0) :: else -> skip fi;
     safe_state_entered(c, why)
  :: else -> skip
  fi
}

/* Runtime::foreign_frame: the latch, and a GFC from channel A's core in Operational. */
inline foreign(c) {
  latch(c, F_FOREIGN);
  if
  :: c == PA && nmt[PA] == OPER -> gfc_pending = gfc_pending + 1; assert(gfc_pending < 4)
  :: else -> skip
  fi
}

/* Runtime::role_reply for a fault the role found. */
inline reply_foreign(c) {
  printf("@%d ch%d: foreign frame on our identifiers\n", tick_count, c);
  send_link(c, M_FOREIGN, 0);
  foreign(c)
}
inline reply_transmit_mismatch(c) {
  if
  :: fault[c] == 0 -> send_link(c, M_MISMATCH, 0); latch(c, F_TRANSMIT)
  :: else -> skip
  fi
}

/* ======================================================================================
 * Producer channel A: Runtime::put_on_bus, core_frame, release_waiting; ChannelA::outgoing.
 * ==================================================================================== */
inline put_on_bus_plain(v) {
  ann_num = (ann_num + 1) % 2;
  printf("@%d A: announces and sends plain %d\n", tick_count, v);
  send_link(PA, M_PLAIN, ann_num * 2 + v);
  assert(nfull(tx_a));                 /* model bound: the transmit queue */
  tx_a!FRAME(ID_PLAIN, S_A, ann_num, v)
}

/* ChannelA::outgoing: a pair awaited keeps the newest data for later. */
inline outgoing_a(v) {
  if
  :: awaited != NONE -> deferred = v
  :: else -> awaited = v; awaited_cd = REFRESH_T; put_on_bus_plain(v)
  fi
}

/* Runtime::core_frame */
inline core_frame_a(v) {
  if
  :: (handed == NONE || handed != v) && dage[PA] != NONE && dage[PA] < W_T ->
     waiting = v
  :: else ->
     waiting = NONE; handed = v;
     outgoing_a(v)
  fi
}

/* Runtime::release_waiting */
inline release_waiting() {
  if
  :: waiting != NONE && (dage[PA] == NONE || dage[PA] >= W_T) ->
     tmp = waiting; waiting = NONE;
     if :: fault[PA] == 0 -> core_frame_a(tmp) :: else -> skip fi
  :: else -> skip
  fi
}

/* The core's transmit SRDO (srdo::Producer, Device::poll): the plain frame of A's sample. */
inline core_transmit_a() {
  if
  :: nmt[PA] == OPER && !core_safe[PA] && (changed || refresh_cd == 0) ->
     changed = 0; refresh_cd = REFRESH_T;
     if :: fault[PA] == 0 -> core_frame_a(sampled[PA]) :: else -> skip fi
  :: else -> skip
  fi
}

/* ChannelA::observe */
inline observe_a(f) {
  if
  :: FID(f) == ID_PLAIN -> reply_foreign(PA)     /* never our own: we do not receive it */
  :: FID(f) == ID_INV ->
     if
     :: !(awaited != NONE && awaited == FDATA(f)) && cut != NONE && cut == FDATA(f) ->
        printf("@%d A: inverted %d ends the pair cut by the reset\n", tick_count, FDATA(f));
        cut = NONE; cut_cd = NONE
     :: else ->
        if
        :: awaited == NONE -> reply_foreign(PA)
        :: awaited != NONE && awaited != FDATA(f) ->
           deferred = NONE;
           if :: fault[PA] == 0 -> latch(PA, F_INVERTED) :: else -> skip fi
        :: else ->
           awaited = NONE; awaited_cd = NONE;
           if
           :: deferred != NONE ->
              tmp = deferred; deferred = NONE;
              awaited = tmp; awaited_cd = REFRESH_T;
              if :: fault[PA] == 0 -> put_on_bus_plain(tmp) :: else -> skip fi
           :: else -> skip
           fi
        fi
     fi
  :: else -> skip
  fi
}

/* ChannelA::reset: every pair awaited is cut. */
inline reset_a() {
#ifdef MUTATION_CUT_PAIR_FOREIGN
  cut = NONE; cut_cd = NONE;
#else
  cut = awaited; cut_cd = awaited_cd;
#endif
  awaited = NONE; awaited_cd = NONE; deferred = NONE
}

/* ======================================================================================
 * Producer channel B: ChannelB::co_sign, observe, announced, input, reset, peer_reset.
 * ==================================================================================== */
/* `left`: ticks of the window still to run, counted from the bus frame's arrival. */
inline co_sign(f, left) {
  if
  :: held != NONE -> held = NONE; held_cd = NONE; reply_transmit_mismatch(PB)
  :: else ->
     if
     :: FDATA(f) == sampled[PB] || (prev != NONE && prev_age < W_T && prev == FDATA(f)) ->
        /* Only a value B's own inputs read within the window, so both channels agreed. */
        assert(FDATA(f) == sampled[PB] || (prev == FDATA(f) && prev_age < W_T));
        send_inverted(f, gseen_ep)
     :: else ->
        printf("@%d B: holds plain %d for its next sample\n", tick_count, FDATA(f));
        held = f; held_cd = left; held_ep = gseen_ep
     fi
  fi;
  gseen_ep = 0
}

/* `ep`: B's epoch when it saw the frame on the bus. The reset property: B never co-signs a
 * frame it saw before its own last NMT reset (after reset communication nothing from before
 * acts; channel A cut that pair). */
inline send_inverted(f, ep) {
  if
  :: ep != epoch[PB] ->
     printf("@%d PROPERTY reset: B co-signs a frame it saw before its own reset\n", tick_count)
  :: else -> skip
  fi;
  assert(ep == epoch[PB]);
  if
  :: fault[PB] == 0 ->
     printf("@%d B: co-signs plain %d\n", tick_count, FDATA(f));
     assert(nfull(tx_b));
     tx_b!FRAME(ID_INV, S_B, FNUM(f), FDATA(f))
  :: else -> skip
  fi
}

/* The co-sign property: B co-signs channel A's frame only against that frame's own
 * announcement, and a frame of anyone else only when it equals an announcement (channel A,
 * which never receives its own frames, reports it). */
inline cosign_property(f, a) {
  if
  :: FSRC(f) == S_A && FNUM(f) != FNUM(a) ->
     printf("@%d PROPERTY co-sign: B co-signs A's frame against another announcement\n", tick_count)
  :: FSRC(f) != S_A && !injected ->
     printf("@%d PROPERTY co-sign: B co-signs a frame A did not send\n", tick_count)
  :: else -> skip
  fi;
  assert(FDATA(f) == FDATA(a));
  assert(FSRC(f) != S_A || FNUM(f) == FNUM(a));
  assert(FSRC(f) == S_A || injected)
}

/* A plain frame equal to A's announcement of its ended epoch (ChannelB::ended): A's frame of
 * that epoch, which reached the bus after A's reset; nobody co-signs it, and it is not foreign.
 * The frame let go is the one announced (A's frames of one identifier keep their order). */
#define ENDED_MATCH(f) (ended != NONE && FID(f) == ID_PLAIN && FDATA(f) == FDATA(ended))
inline let_ended_go(f) {
  printf("@%d B: lets A's plain %d of the ended epoch go by\n", tick_count, FDATA(f));
  assert(FSRC(f) != S_A || FNUM(f) == FNUM(ended));
  ended = NONE; ended_cd = NONE
}

/* Between B's reset and A's heartbeat of the new epoch (b_lead 2), a plain frame B saw before
 * its announcement and followed by one with other data may be A's of the ended epoch, its
 * announcement ahead of that heartbeat on the link: kept for it (ended_unannounced, if free),
 * and the new one waits for its own (ChannelB::observe_seen). -DMUTATION_SECOND_UNANNOUNCED_FOREIGN:
 * the second frame is foreign at once (the Rust before that fix). */
#ifdef MUTATION_SECOND_UNANNOUNCED_FOREIGN
#define KEEP_FOR_ANNOUNCEMENT false
#else
#define KEEP_FOR_ANNOUNCEMENT (b_lead == 2 && !(ended_unann != NONE && ended_unann_cd > 0))
#endif

inline observe_b(f) {
  if
  :: FID(f) == ID_INV -> reply_foreign(PB)
  :: FID(f) == ID_PLAIN && ENDED_MATCH(f) -> let_ended_go(f)
  :: FID(f) == ID_PLAIN && !ENDED_MATCH(f) ->
     ended = NONE; ended_cd = NONE;    /* not that frame: it was lost, the announcement goes */
     if
     :: announced != NONE ->
        tmp = announced; announced = NONE;
        if
        :: FDATA(tmp) == FDATA(f) -> cosign_property(f, tmp); gseen_ep = epoch[PB]; co_sign(f, W_T)
        :: else -> reply_foreign(PB)
        fi
     :: announced == NONE && unann != NONE && FDATA(unann) == FDATA(f) ->
        skip                                 /* the same frame twice before its announcement */
     :: announced == NONE && unann != NONE && FDATA(unann) != FDATA(f) && !KEEP_FOR_ANNOUNCEMENT ->
        reply_foreign(PB)
     :: else ->
        /* No frame waits for its announcement, or one is kept for it (KEEP_FOR_ANNOUNCEMENT). */
        ended_unann_cd = (unann != NONE -> unann_cd : ended_unann_cd);
        ended_unann = (unann != NONE -> unann : ended_unann);
        unann = f; unann_cd = W_T; unann_ep = epoch[PB]
     fi
  :: else -> skip
  fi
}

/* ChannelB::announced; `a` is the announcement as a frame. */
inline announced_b(a) {
  if
  :: ended_unann != NONE && ended_unann_cd > 0 ->
     /* The announcement of the frame B saw before its own reset (ended_unannounced): the pair
      * was cut by that reset, nothing is co-signed; otherwise than it came, it was foreign. */
     tmp = ended_unann; ended_unann = NONE; ended_unann_cd = NONE;
     if
     :: FDATA(tmp) == FDATA(a) ->
        printf("@%d B: announcement of plain %d kept for it, not co-signed\n", tick_count, FDATA(a));
        assert(FSRC(tmp) != S_A || FNUM(tmp) == FNUM(a))
     :: else -> reply_foreign(PB)
     fi
  :: unann != NONE && !(ended_unann != NONE && ended_unann_cd > 0) ->
     ended_unann = NONE; ended_unann_cd = NONE;
     tmp = unann; unann = NONE;
     if
     :: FDATA(tmp) == FDATA(a) -> cosign_property(tmp, a); gseen_ep = unann_ep; co_sign(tmp, unann_cd)
     :: else -> reply_foreign(PB)
     fi;
     unann_cd = NONE
  :: else -> ended_unann = NONE; ended_unann_cd = NONE; announced = a
  fi
}

/* ChannelB::input */
inline input_b(v) {
  if :: v != sampled[PB] -> prev = sampled[PB]; prev_age = 0 :: else -> skip fi;
  sampled[PB] = v;
  if
  :: held != NONE && FDATA(held) == v ->
     tmp = held; held = NONE; held_cd = NONE;
     send_inverted(tmp, held_ep)
  :: else -> skip
  fi
}

/* ChannelB::reset: the held frame is forgotten; one not announced yet is kept for its
 * announcement (ended_unannounced), never co-signed. */
inline reset_b() {
  b_lead = b_lead + (b_lead < 2);
#ifdef MUTATION_COSIGN_BEFORE_RESET
  skip
#else
  held = NONE; held_cd = NONE;
#ifdef MUTATION_FORGET_ENDED_EPOCH
  unann = NONE; unann_cd = NONE
#else
  if
  :: unann != NONE -> ended_unann = unann; ended_unann_cd = unann_cd; unann = NONE; unann_cd = NONE
  :: else -> skip
  fi
#endif
#endif
}

/* ChannelB::peer_reset: A's announcements of its ended epoch set apart (ended), and
 * Runtime::on_message's offer of the frames kept before Operational (Role::ended_frame). */
inline peer_reset_b() {
  b_lead = b_lead - (b_lead > 0);
#ifdef MUTATION_KEEP_ANNOUNCEMENTS
  skip
#elif defined(MUTATION_FORGET_ENDED_EPOCH)
  announced = NONE
#else
  if :: announced != NONE -> ended = announced; announced = NONE :: else -> skip fi;
  if :: ended != NONE -> ended_cd = W_T + 1 :: else -> skip fi;
  if
  :: early[PB] != NONE && ENDED_MATCH(early[PB]) ->
     tmp2 = early[PB]; early[PB] = NONE; early_cd[PB] = NONE; let_ended_go(tmp2)
  :: else -> skip
  fi
#endif
}

/* ======================================================================================
 * Runtime: inputs, NMT check, the core's NMT and SRDO handling, after_core, on_frame,
 * on_message, poll.
 * ==================================================================================== */
/* InputCheck::compare */
inline compare_inputs(c) {
  if
  :: peer_in[c] != NONE && peer_in[c] != sampled[c] ->
     if :: dage[c] == NONE -> dage[c] = 0 :: else -> skip fi
  :: else -> dage[c] = NONE
  fi
}

/* Runtime::peer_inputs */
inline peer_inputs(c, v) {
  peer_in[c] = v;
  compare_inputs(c);
  if :: c == PA -> release_waiting() :: else -> skip fi
}

/* Runtime::set_input, with the core's poll for channel A (its object changed). */
inline set_input(c, v) {
  printf("@%d ch%d: samples input %d\n", tick_count, c, v);
  if
  :: c == PB -> input_b(v)
  :: else -> sampled[PA] = v; changed = 1
  fi;
  send_link(c, M_INPUTS, v);
  compare_inputs(c);
  if
  :: c == PA -> core_transmit_a(); release_waiting()
  :: else -> skip
  fi
}

/* NmtCheck::compare */
inline nmt_compare(c) {
  if
  :: peer_epoch[c] == NONE || (peer_epoch[c] == epoch[c] && peer_nmt[c] == nmt[c]) ->
     nmt_cd[c] = NONE
  :: else ->
     if :: nmt_cd[c] == NONE -> nmt_cd[c] = TIMEOUT_T :: else -> skip fi
  fi
}

/* Runtime::follow_core */
inline follow_core(c) {
  if :: !(nmt[c] == OPER && !core_safe[c]) -> clear_outputs(c) :: else -> skip fi;
  if
  :: nmt[c] != OPER && c >= CA ->
     do :: vloc[c - CA]?_, _ :: empty(vloc[c - CA]) -> break od;
     do :: vrem[c - CA]?_, _ :: empty(vrem[c - CA]) -> break od;
     pairs[c - CA] = 0; peer_pairs[c - CA] = 0
  :: else -> skip
  fi;
  if :: nmt[c] != OPER -> cfg_ok[c] = 0 :: else -> skip fi;
  if :: nmt[c] == PREOP && !core_safe[c] -> fault[c] = 0 :: else -> skip fi
}

/* NMT reset communication: the core (Initialising, then Pre-operational, its safe state
 * cleared) and after_core's NmtState(Initialising) and NmtState(PreOperational). */
inline nmt_reset(c) {
  printf("@%d ch%d: NMT reset\n", tick_count, c);
  nmt[c] = PREOP; core_safe[c] = 0;
  epoch[c] = (epoch[c] + 1) % 4;
  if
  :: c == PA ->
#ifdef WITHDRAW_AT_RESET
     /* A candidate fix of the first reset trail (docs/model-checking.md), not the Rust
      * (channel B sets such a frame apart instead): channel A withdraws its plain frames not
      * yet on the bus at NMT reset. */
     do :: nempty(tx_a) -> tx_a?_ :: empty(tx_a) -> break od;
#endif
     reset_a(); waiting = NONE; handed = NONE; refresh_cd = NONE; changed = 0
  :: c == PB -> reset_b()
  :: else ->
     pend[c - CA] = NONE; srvt_cd[c - CA] = NONE; sct_cd[c - CA] = NONE;
     got_pair[c - CA] = 0
  fi;
  if :: c < CA && dage[c] != NONE -> dage[c] = 0 :: else -> skip fi;  /* InputCheck::restart */
  follow_core(c);
  heartbeat(c);
  nmt_compare(c)
}

/* Runtime::observe_early */
inline observe_early(c) {
  if
  :: early[c] != NONE ->
     tmp2 = early[c]; early[c] = NONE;
     if
     :: early_cd[c] > 0 && fault[c] == 0 ->
        printf("@%d ch%d: observes the frame seen before Operational\n", tick_count, c);
        if :: c == PA -> observe_a(tmp2) :: else -> observe_b(tmp2) fi
     :: else -> skip
     fi
  :: else -> skip
  fi
}

/* NMT start: the core enters Operational (producer and consumer start), after_core. */
inline nmt_start(c) {
  if
  :: nmt[c] == PREOP ->
     printf("@%d ch%d: NMT start\n", tick_count, c);
     nmt[c] = OPER;
     if
     :: c == PA -> refresh_cd = TICKS(PRODUCER_START_US); changed = 0
     :: c >= CA -> pend[c - CA] = NONE; sct_cd[c - CA] = SCT_T; srvt_cd[c - CA] = NONE;
        paired[c - CA] = 0
     :: else -> skip
     fi;
     follow_core(c);
     if :: c < CA -> observe_early(c) :: else -> skip fi;
     heartbeat(c);
     nmt_compare(c)
  :: else -> skip
  fi
}

/* The core's safe state on a fault it found (an SRDO fault, a GFC): after_core's
 * Event::SafeState tells the other channel at once. */
inline core_fault(c, why) {
  printf("@%d ch%d: core safe state, cause %d\n", tick_count, c, why);
  safe_state_entered(c, why);
  send_link(c, M_SAFE, 0);
  follow_core(c)
}

/* Runtime::drive, with the output property. */
inline drive(k, v) {
  tmp4 = outp[k];
  if
  :: WORKING(CA + k) -> outp[k] = v
  :: else -> outp[k] = 0
  fi;
  if
  :: outp[k] == 1 && tmp4 == 0 ->
     if
     :: !(gnew[k] == 1 && gpeer_pair[k] == pairs[k] && gpeer_data[k] == 1) ->
        printf("@%d PROPERTY output: ch%d on without its newest pair confirmed\n", tick_count, CA + k)
     :: else -> skip
     fi;
     /* Output rule: an output leaves the safe state only with the newest pair this
      * channel's core accepted, carrying 1, confirmed by the other channel's verdict on that
      * same pair with nothing newer reported, and made of the producer's two channels'
      * frames (unless a foreign frame was injected: the foreign-frame property covers it). */
     assert(gnew[k] == 1);
     assert(gpeer_pair[k] == pairs[k] && gpeer_data[k] == 1);
     assert(gnew_genuine[k] || injected)
  :: else -> skip
  fi;
  tmp4 = 0
}

/* Runtime::confirmed */
inline confirmed(k, pd) {
  printf("@%d ch%d: pair %d confirmed, data %d\n", tick_count, CA + k, pd / 2, pd % 2);
  got_pair[k] = 1;
  if
  :: cfg_ok[CA + k] ->
#ifdef MUTATION_STALE_CONFIRMATION
     drive(k, pd % 2)
#else
     if
     :: pairs[k] == pd / 2 && peer_pairs[k] == pd / 2 -> drive(k, pd % 2)
     :: else -> drive(k, outp[k] & (pd % 2))
     fi
#endif
  :: else -> skip
  fi
}

/* VerdictCheck::local / remote: `mine` and `theirs` are the two queues. */
inline verdict_arrive(k, pd, mine, theirs) {
  if
  :: nempty(theirs) ->
     theirs?tmp3, _;
     if
     :: tmp3 == pd -> confirmed(k, pd)
     :: else -> latch(CA + k, F_CROSS)
     fi
  :: empty(theirs) && nfull(mine) -> mine!pd, TIMEOUT_T
  :: empty(theirs) && full(mine) ->
     do :: mine?_, _ :: empty(mine) -> break od;
     latch(CA + k, F_CROSS)
  fi
}

/* Runtime::local_pair */
inline local_pair(k, v) {
  pairs[k] = (pairs[k] + 1) % PAIR_MOD;
  send_link(CA + k, M_VERDICT, pairs[k] * 2 + v);
  drive(k, outp[k] & v);
  verdict_arrive(k, pairs[k] * 2 + v, vloc[k], vrem[k])
}

/* Before the consumer's first pair since its start, a half that does not pair (of a pair the
 * producer's reset cut, on the bus after the start) is discarded, and SRVT and SCT decide
 * (srdo::Consumer::on_plain). -DMUTATION_FIRST_PAIR_STRICT: judged as strictly as after it
 * (the Rust before the fix of the finding on the consumer's first pair). */
#ifdef MUTATION_FIRST_PAIR_STRICT
#define BEFORE_FIRST_PAIR(k) false
#else
#define BEFORE_FIRST_PAIR(k) (!paired[k])
#endif

/* The core's SRDO consumer (srdo::Consumer) on a frame of SRDO 1. */
inline consumer_frame(k, f) {
  if
  :: FID(f) == ID_PLAIN ->
     if
     :: pend[k] == NONE -> pend[k] = f; srvt_cd[k] = SRVT_T
     :: pend[k] != NONE && FDATA(pend[k]) == FDATA(f) -> skip    /* an exact repeat */
     :: pend[k] != NONE && FDATA(pend[k]) != FDATA(f) && BEFORE_FIRST_PAIR(k) ->
        pend[k] = f                        /* replaced; SRVT runs on from the first */
     :: else -> core_fault(CA + k, F_SRDO)
     fi
  :: FID(f) == ID_INV ->
     if
     :: pend[k] == NONE || (FDATA(pend[k]) != FDATA(f) && BEFORE_FIRST_PAIR(k)) ->
        skip        /* no plain frame pending, or before the first pair not its inverse */
     :: pend[k] != NONE && FDATA(pend[k]) == FDATA(f) ->
        gnew[k] = FDATA(f);
        gnew_genuine[k] = (FSRC(pend[k]) == S_A && FSRC(f) == S_B);
        pend[k] = NONE; srvt_cd[k] = NONE; sct_cd[k] = SCT_T; paired[k] = 1;
        printf("@%d ch%d: core accepts a pair, data %d\n", tick_count, CA + k, FDATA(f));
        local_pair(k, FDATA(f))
     :: else -> core_fault(CA + k, F_SRDO)
     fi
  fi
}

/* Runtime::on_frame: the role first (in Operational), the frame kept for the window before
 * Operational, then the core. */
inline on_frame(c, f) {
  if
  :: c < CA && nmt[c] == OPER && IS_SRDO(f) ->
     if :: c == PA -> observe_a(f) :: else -> observe_b(f) fi
  :: c == PB && nmt[c] != OPER && ENDED_MATCH(f) -> let_ended_go(f)   /* Role::ended_frame */
  :: c < CA && nmt[c] != OPER && IS_SRDO(f) && !(c == PB && ENDED_MATCH(f)) ->
     early[c] = f; early_cd[c] = W_T
  :: else -> skip
  fi;
  if
  :: FID(f) == ID_START -> nmt_start(c)
  :: FID(f) == ID_RESET -> nmt_reset(c)
  :: FID(f) == ID_GFC ->
     if
     :: nmt[c] == OPER && !core_safe[c] -> core_fault(c, F_GFC)
     :: else -> skip
     fi
  :: IS_SRDO(f) && c >= CA && nmt[c] == OPER && !core_safe[c] -> consumer_frame(c - CA, f)
  :: else -> skip
  fi
}

/* Runtime::on_link_completed and on_message. */
inline on_message(c, m) {
  if
  :: lost[c] -> lost[c] = 0; latch(c, F_LINK)     /* LinkFault::Missing */
  :: else ->
     if
     :: MTYPE(m) == M_HB ->
        tmp = peer_epoch[c];
        peer_epoch[c] = (MPAY(m) / 2) % 4; peer_nmt[c] = MPAY(m) / 8;
        nmt_compare(c);
        if
        :: tmp != NONE && tmp != peer_epoch[c] && c == PB ->
           printf("@%d B: A's heartbeat names a new epoch\n", tick_count);
           peer_reset_b()
        :: else -> skip
        fi;
        if
        :: SAME_EPOCH(c) ->
           if :: peer_nmt[c] == OPER && nmt[c] == OPER -> cfg_ok[c] = 1 :: else -> skip fi;
           if :: c < CA -> peer_inputs(c, MPAY(m) % 2) :: else -> skip fi
        :: else -> skip
        fi
#ifdef MUTATION_DROP_ANNOUNCEMENTS
     :: MTYPE(m) != M_HB && !SAME_EPOCH(c) ->
#else
     :: MTYPE(m) != M_HB && MTYPE(m) != M_PLAIN && !SAME_EPOCH(c) ->
#endif
        printf("@%d ch%d: ignores link message %d of another epoch\n", tick_count, c, MTYPE(m))
     :: else ->
        if
        :: MTYPE(m) == M_INPUTS -> if :: c < CA -> peer_inputs(c, MPAY(m)) :: else -> skip fi
        :: MTYPE(m) == M_VERDICT ->
           if
           :: nmt[c] == OPER && c >= CA ->
              peer_pairs[c - CA] = MPAY(m) / 2;
              gpeer_pair[c - CA] = MPAY(m) / 2; gpeer_data[c - CA] = MPAY(m) % 2;
              verdict_arrive(c - CA, MPAY(m), vrem[c - CA], vloc[c - CA])
           :: else -> skip
           fi
        :: MTYPE(m) == M_MISMATCH -> latch(c, F_TRANSMIT)
        :: MTYPE(m) == M_PLAIN ->
           if
           :: c == PB ->
              printf("@%d B: announcement of plain %d\n", tick_count, MPAY(m) % 2);
              announced_b(FRAME(ID_PLAIN, S_A, MPAY(m) / 2, MPAY(m) % 2))
           :: else -> skip
           fi
        :: MTYPE(m) == M_FOREIGN -> foreign(c)
        :: MTYPE(m) == M_SAFE ->
           if :: fault[c] == 0 && !core_safe[c] -> latch(c, F_PEER) :: else -> skip fi
        fi
     fi
  fi
}

/* Something for Runtime::poll at this tick (a deadline reached). A changed input is due for
 * the core's producer only while it runs (as core_transmit_a takes it): otherwise the poll
 * would find it due again and again, and time would stop (no tick while a poll is due). */
#define POLL_DUE(c) \
  (nmt_cd[c] == 0 || \
   (c < CA && fault[c] == 0 && dage[c] == DISC_T) || \
   (c == PA && (refresh_cd == 0 || (changed && nmt[PA] == OPER && !core_safe[PA]) || \
                awaited_cd == 0 || cut_cd == 0 || \
                (waiting != NONE && (dage[PA] == NONE || dage[PA] >= W_T)))) || \
   (c == PB && (held_cd == 0 || unann_cd == 0)) || \
   (c >= CA && (srvt_cd[c - CA] == 0 || sct_cd[c - CA] == 0 || \
                vloc[c - CA]?[_, 0] || vrem[c - CA]?[_, 0])))

/* Runtime::poll */
inline poll(c) {
  if :: c == PA -> core_transmit_a(); if :: refresh_cd == 0 -> refresh_cd = NONE :: else -> skip fi
     :: else -> skip fi;
  if
  :: c >= CA && srvt_cd[c - CA] == 0 -> srvt_cd[c - CA] = NONE; core_fault(c, F_SRDO)
  :: c >= CA && sct_cd[c - CA] == 0 -> sct_cd[c - CA] = NONE; core_fault(c, F_SRDO)
  :: else -> skip
  fi;
  /* Role::poll */
  if
  :: c == PA && cut_cd == 0 -> cut = NONE; cut_cd = NONE
  :: else -> skip
  fi;
  if
  :: c == PA && awaited_cd == 0 ->
     awaited = NONE; awaited_cd = NONE; deferred = NONE; reply_transmit_mismatch(PA)
  :: else -> skip
  fi;
  if
  :: c == PB && unann_cd == 0 -> unann = NONE; unann_cd = NONE; reply_foreign(PB)
  :: else -> skip
  fi;
  if
  :: c == PB && held_cd == 0 -> held = NONE; held_cd = NONE; reply_transmit_mismatch(PB)
  :: else -> skip
  fi;
  if :: c == PA -> release_waiting() :: else -> skip fi;
  /* VerdictCheck::poll */
  if
  :: c >= CA && (vloc[c - CA]?[_, 0] || vrem[c - CA]?[_, 0]) ->
     do :: vloc[c - CA]?_, _ :: empty(vloc[c - CA]) -> break od;
     do :: vrem[c - CA]?_, _ :: empty(vrem[c - CA]) -> break od;
     latch(c, F_CROSS)
  :: else -> skip
  fi;
  if :: nmt_cd[c] == 0 -> nmt_cd[c] = NONE; latch(c, F_NMT) :: else -> skip fi;
  if :: c < CA && fault[c] == 0 && dage[c] == DISC_T -> latch(c, F_INPUT) :: else -> skip fi;
}

/* The output property as an invariant, checked after every step of a consumer channel. */
inline output_invariant(k) {
  assert(outp[k] == 0 || (gnew[k] == 1 && WORKING(CA + k)))
}

/* ======================================================================================
 * Processes
 * ==================================================================================== */
/* One channel's loop (dual_channel::channel_loop::ChannelLoop::service): a frame from its
 * receive queue, a link message, a changed input pin, or what is due. */
#ifdef LIVENESS
/* A frame's handling with the liveness run's ghost code is longer than SPIN allows a d_step
 * ("d_step sequence too long"): atomic there, which explores the same behaviours (the body
 * neither blocks nor branches on another process) with its inner states stored. */
#define FRAME_STEP atomic
#else
#define FRAME_STEP d_step
#endif
proctype Channel(byte c) {
  byte f, m, tmp, tmp2, tmp3, tmp4, d;
  do
  :: FRAME_STEP { !env_turn && nempty(rx[c]) -> rx[c]?f;
       if
       :: rx_late[c] > 0 -> rx_late[c]--; printf("@%d ch%d: (late) a frame of the last tick\n", tick_count, c)
       :: else -> skip
       fi;
       on_frame(c, f); f = 0; tmp = 0; tmp2 = 0; tmp3 = 0 }
  :: d_step { !env_turn && (empty(rx[c]) || LAGS(c)) && link[c]?[m, d] ->
       link[c]?m, d; on_message(c, m); m = 0; d = 0; tmp = 0; tmp2 = 0; tmp3 = 0 }
  :: d_step { !env_turn && (empty(rx[c]) || LAGS(c)) && c < CA && pin[c] != sampled[c] ->
       set_input(c, pin[c]); tmp = 0; tmp2 = 0; tmp3 = 0 }
  :: d_step { !env_turn && (empty(rx[c]) || LAGS(c)) && rx_late[c] == 0 && POLL_DUE(c) -> poll(c); tmp = 0; tmp2 = 0; tmp3 = 0 }
  od
}

/* The bus: arbitration (lowest identifier first), delivery to every other controller (a
 * controller never receives its own frames), loss. */
#define DELIVER(f, from) \
  if :: from != PA -> assert(nfull(rx[PA])); rx[PA]!f :: else -> skip fi; \
  if :: from != PB -> assert(nfull(rx[PB])); rx[PB]!f :: else -> skip fi; \
  assert(nfull(rx[CA])); rx[CA]!f; assert(nfull(rx[CB])); rx[CB]!f

inline on_bus(f, from) {
  if
  :: bus_drop -> bus_drop = 0; printf("@%d bus: frame %d lost\n", tick_count, f)
  :: else ->
     printf("@%d bus: id %d data %d from %d\n", tick_count, FID(f), FDATA(f), FSRC(f));
     if :: FID(f) == ID_GFC -> gfc_sent = 1 :: else -> skip fi;
     if :: FID(f) == ID_RESET -> foreign_cd = NONE :: else -> skip fi;
     if
     :: FSRC(f) == S_X && nmt[PA] == OPER && nmt[PB] == OPER &&
        !(rx[PA]??[RESET_FRAME]) && !(rx[PB]??[RESET_FRAME]) ->
        foreign_cd = P_LATENCY_T + 1; gfc_sent = 0
     :: else -> skip
     fi;
     DELIVER(f, from)
  fi
}

#define ROOM (!env_turn && nfull(rx[PA]) && nfull(rx[PB]) && nfull(rx[CA]) && nfull(rx[CB]))

/* A frame goes on the bus only when every receive queue has room: the loops keep up with
 * the bus (a receive overrun is its own fault, ChannelFault::ReceiveOverrun, not modelled). */
proctype Bus() {
  byte f;
  do
  :: atomic { ROOM && M_READY -> tx_m?f; on_bus(f, 4); f = 0 }
  :: atomic { ROOM && M_WAITS && gfc_pending > 0 ->
       gfc_pending = gfc_pending - 1; on_bus(FRAME(ID_GFC, S_A, 0, 0), PA) }
  :: atomic { ROOM && M_WAITS && gfc_pending == 0 && nempty(tx_a) -> tx_a?f; on_bus(f, PA); f = 0 }
  :: atomic { ROOM && M_WAITS && gfc_pending == 0 && foreign_frame != NONE && FID(foreign_frame) == ID_PLAIN ->
       f = foreign_frame; foreign_frame = NONE; on_bus(f, 4); f = 0 }
  :: atomic { ROOM && M_WAITS && gfc_pending == 0 && empty(tx_a) &&
       !(foreign_frame != NONE && FID(foreign_frame) == ID_PLAIN) && nempty(tx_b) ->
       tx_b?f; on_bus(f, PB); f = 0 }
  :: atomic { ROOM && M_WAITS && gfc_pending == 0 && empty(tx_a) && foreign_frame != NONE &&
       FID(foreign_frame) == ID_INV -> f = foreign_frame; foreign_frame = NONE; on_bus(f, 4); f = 0 }
  od
}

/* Nothing left to do at this instant: every frame is on the bus and handled, every message
 * whose latency is used up delivered, every deadline polled, every pin sampled. */
#define QUIET \
  (RX_DONE(PA) && RX_DONE(PB) && RX_DONE(CA) && RX_DONE(CB) && \
   empty(tx_m) && empty(tx_a) && empty(tx_b) && gfc_pending == 0 && foreign_frame == NONE && \
   !(link[PA]?[_, 0]) && !(link[PB]?[_, 0]) && !(link[CA]?[_, 0]) && !(link[CB]?[_, 0]) && \
   !POLL_DUE(PA) && !POLL_DUE(PB) && !POLL_DUE(CA) && !POLL_DUE(CB) && \
   pin[PA] == sampled[PA] && pin[PB] == sampled[PB] && gap_cd != 0)

inline age_link(q) {
  d = len(q);
  do
  :: d > 0 -> q?f, e; if :: e > 0 -> q!f, e - 1 :: else -> q!f, e fi; d--
  :: else -> break
  od
}

/* Time: one tick, when nothing is left to do tick_count. */
proctype Clock() {
  byte c, d, f, e;
  do
  :: d_step { !env_turn && QUIET ->
       tick_count++; env_turn = 1;
       c = 0;
       do
       :: c < 4 ->
          DEC(nmt_cd[c]);
          age_link(link[c]);
          if :: LATE(c) -> rx_late[c] = len(rx[c]) :: else -> skip fi;
          c++
       :: else -> break
       od;
       c = 0;
       do
       :: c < 2 ->
          if :: dage[c] != NONE && dage[c] < DISC_T -> dage[c]++ :: else -> skip fi;
          DEC(early_cd[c]);
          DEC(srvt_cd[c]); DEC(sct_cd[c]);
          age_link(vloc[c]); age_link(vrem[c]);
          c++
       :: else -> break
       od;
       DEC(refresh_cd); DEC(awaited_cd); DEC(cut_cd); DEC(held_cd); DEC(unann_cd);
       /* Ghosts of frames B no longer keeps (fewer states). */
       if :: unann == NONE -> unann_ep = 0 :: else -> skip fi;
       if :: held == NONE -> held_ep = 0 :: else -> skip fi;
       /* ChannelB::expire_ended: A's announcement of its ended epoch goes at least a window
        * after A's heartbeat of the new epoch (Rust: exactly the window; the model's timers
        * fire up to a tick early, so it keeps it a tick more). */
       if
       :: ended_cd != NONE && ended_cd <= 1 -> ended = NONE; ended_cd = NONE
       :: else -> DEC(ended_cd)
       fi;
       /* ChannelB::expire: the frame seen before B's reset goes at the window's end. */
       if
       :: ended_unann_cd != NONE && ended_unann_cd <= 1 -> ended_unann = NONE; ended_unann_cd = NONE
       :: else -> DEC(ended_unann_cd)
       fi;
       if :: prev_age < W_T -> prev_age++ :: else -> skip fi;
       DEC(gap_cd);
#ifdef LIVENESS
       DEC(restart_cd);
#endif
       if :: reset_age < START_AFTER_RESET_T -> reset_age++ :: else -> reset_age = 255 fi;
       if
       :: foreign_cd != NONE ->
          if
          :: foreign_cd == 0 ->
             /* A foreign frame on the producer's identifiers takes the producer's two
              * channels to their safe state and puts a GFC on the bus, and the consumer's
              * outputs are off, within the bound. */
             if
             :: !(fault[PA] != 0 && fault[PB] != 0 && gfc_sent && outp[0] == 0 && outp[1] == 0) ->
                printf("@%d PROPERTY foreign frame: the node not safe in time\n", tick_count)
             :: else -> skip
             fi;
             assert(fault[PA] != 0 && fault[PB] != 0 && gfc_sent && outp[0] == 0 && outp[1] == 0);
             foreign_cd = NONE
          :: else -> foreign_cd--
          fi
       :: else -> skip
       fi;
       c = 0; d = 0; f = 0; e = 0 }
  od
}

/* The environment: the NMT master, the two contacts, and the faults. */
proctype Environment() {
  do
  /* Nothing (more) at this tick. */
  :: atomic { env_turn && gap_cd != 0 && !(again && !start_due && restart_cd == 0 && len(tx_m) == 0) &&
              !(start_due && reset_age >= START_AFTER_RESET_T) -> env_turn = 0 }
  /* NMT commands to all nodes, at any moment (also between two frames of a tick). */
  :: atomic { nmt_left > 0 && MASTER_MAY_SEND && nfull(tx_m) && reset_age >= START_AFTER_RESET_T ->
       nmt_left--; tx_m!FRAME(ID_START, S_M, 0, 0) }
  :: atomic { nmt_left > 0 && MASTER_MAY_SEND && nfull(tx_m) ->
       nmt_left--; tx_m!FRAME(ID_RESET, S_M, 0, 0); reset_age = 0 }
  /* An input change: one contact, then the other within the contact gap (fault-free). */
  :: atomic { env_turn && input_left > 0 && pin[PA] == pin[PB] && gap_cd == NONE ->
       input_left--; pin[PA] = !pin[PA]; gap_cd = CONTACT_GAP_T }
  :: atomic { env_turn && input_left > 0 && pin[PA] == pin[PB] && gap_cd == NONE ->
       input_left--; pin[PB] = !pin[PB]; gap_cd = CONTACT_GAP_T }
  :: atomic { env_turn && gap_cd != NONE && pin[PA] != pin[PB] -> pin[PA] = pin[PB]; gap_cd = NONE }
  :: atomic { env_turn && gap_cd != NONE && pin[PA] != pin[PB] -> pin[PB] = pin[PA]; gap_cd = NONE }
  /* Faults. */
  :: atomic { env_turn && fault_left > 0 && STUCK_FAULTS && gap_cd != NONE ->       /* a contact stuck */
       fault_left--; injected = 1; gap_cd = NONE; printf("@%d env: contact stuck\n", tick_count) }
  :: atomic { env_turn && fault_left > 0 && FOREIGN_FAULTS && foreign_frame == NONE ->
       fault_left--; injected = 1; foreign_frame = FRAME(ID_PLAIN, S_X, 0, 1);
       printf("@%d env: foreign plain frame 1 queued\n", tick_count) }
  :: atomic { env_turn && fault_left > 0 && FOREIGN_FAULTS && foreign_frame == NONE ->
       fault_left--; injected = 1; foreign_frame = FRAME(ID_PLAIN, S_X, 0, 0);
       printf("@%d env: foreign plain frame 0 queued\n", tick_count) }
  :: atomic { env_turn && fault_left > 0 && FOREIGN_FAULTS && foreign_frame == NONE ->
       fault_left--; injected = 1; foreign_frame = FRAME(ID_INV, S_X, 0, 1);
       printf("@%d env: foreign inverted frame 1 queued\n", tick_count) }
  :: atomic { env_turn && fault_left > 0 && LOSS_FAULTS && !bus_drop ->
       fault_left--; injected = 1; bus_drop = 1; printf("@%d env: next bus frame lost\n", tick_count) }
  :: atomic { env_turn && fault_left > 0 && LOSS_FAULTS ->
       fault_left--; injected = 1;
       if :: link_drop[PA] = 1 :: link_drop[PB] = 1 :: link_drop[CA] = 1 :: link_drop[CB] = 1 fi;
       printf("@%d env: next link message lost\n", tick_count) }
#ifdef LIVENESS
  /* The last move: the contacts repaired, then NMT reset, and start a tick later
   * (START_AFTER_RESET_T; at once, the finding of docs/model-checking.md may stop it). */
  :: atomic { env_turn && !env_done && nfull(tx_m) && len(tx_m) == 0 && gap_cd == NONE ->
       pin[PB] = pin[PA];
       tx_m!FRAME(ID_RESET, S_M, 0, 0); reset_age = 0; start_due = 1;
       nmt_left = 0; input_left = 0; fault_left = 0; env_done = 1 }
  :: atomic { env_turn && start_due && reset_age >= START_AFTER_RESET_T && nfull(tx_m) ->
       start_due = 0; restart_cd = TIMEOUT_T + 1; tx_m!FRAME(ID_START, S_M, 0, 0) }
  /* A fault of before the last move found after it (a GFC channel A sends on channel B's
   * report of a foreign frame, a window after its own; a lost link message found at the next
   * one) stops the network again: the master restarts it, once the NMT check's grace after
   * its last start has passed (sooner, restarts a tick apart keep the channels' NMT states
   * apart on a link slower than a tick, and the NMT check latches). */
  :: atomic { env_turn && again && !start_due && restart_cd == 0 && nfull(tx_m) && len(tx_m) == 0 ->
       again = 0; tx_m!FRAME(ID_RESET, S_M, 0, 0); reset_age = 0; start_due = 1 }
#endif
  od
}

init {
  byte c;
  atomic {
    c = 0;
    do
    :: c < 4 ->
       /* After the start-up handshake (Runtime::on_link_completed: each channel has heard
        * the other's heartbeat, both cores booted into Pre-operational). */
       peer_epoch[c] = 0; peer_nmt[c] = PREOP; nmt_cd[c] = NONE;
       c++
    :: else -> break
    od;
    dage[PA] = NONE; dage[PB] = NONE;
    early[PA] = NONE; early[PB] = NONE; early_cd[PA] = NONE; early_cd[PB] = NONE;
    pend[0] = NONE; pend[1] = NONE; srvt_cd[0] = NONE; srvt_cd[1] = NONE;
    sct_cd[0] = NONE; sct_cd[1] = NONE; gpeer_pair[0] = NONE; gpeer_pair[1] = NONE;
    prev_age = W_T;
    pin[PA] = INITIAL_INPUT; pin[PB] = INITIAL_INPUT;
    sampled[PA] = INITIAL_INPUT; sampled[PB] = INITIAL_INPUT;
    peer_in[PA] = INITIAL_INPUT; peer_in[PB] = INITIAL_INPUT;
    if :: STARTED -> tx_m!FRAME(ID_START, S_M, 0, 0) :: else -> skip fi;
    c = 0;
    run Channel(PA); run Channel(PB); run Channel(CA); run Channel(CB);
    run Bus(); run Clock(); run Environment()
  }
}

#ifdef LIVENESS
/* After the environment's last move (the faults over, the contacts repaired, NMT reset and
 * start), both nodes reach Operational with no fault and the consumer's two channels
 * confirm a pair: under weak fairness (pan -f). */
#define RECOVERED \
  (nmt[PA] == OPER && nmt[PB] == OPER && nmt[CA] == OPER && nmt[CB] == OPER && \
   fault[PA] == 0 && fault[PB] == 0 && fault[CA] == 0 && fault[CB] == 0 && \
   !core_safe[PA] && !core_safe[PB] && !core_safe[CA] && !core_safe[CB] && \
   got_pair[0] && got_pair[1])
ltl recovers { [] (env_done -> <> RECOVERED) }
#endif
