// The WebSocket stream of one session (/api/sessions/{id}/stream): binary
// flatbuffers, one Envelope (file identifier FCW1) per message. Frames are
// decoded by a FrameDecoder into reused buffers; StateChange, Ack and Error
// are turned into plain objects. A lost connection reconnects with
// exponential backoff; the server starts every connection with a
// StateChange and the current Frame, which resynchronises the view.
import * as flatbuffers from 'flatbuffers';
import {
  Ack, Edit, Envelope, ErrorCode, Error as WireError, Frame, Layer, Message, SessionStatus, StateChange,
  Subscribe, Transport, TransportCommand,
} from '@wire';
import { Signal } from '../core/Signal';
import type { FrameDecoder, FrameInfo } from './FrameDecoder';
import type { SessionState, SessionStatusName } from './types';

export type ConnectionStatus = 'connecting' | 'open' | 'reconnecting' | 'closed';

export interface StreamState {
  sessionId: string;
  status: SessionStatusName;
  frame: number;
  time: number;
  shownFrame: number;
  live: boolean;
  playbackSpeed: number;
  historyFirst: number;
  historyLast: number;
  historyDropped: number;
  message: string;
  requestId: number;
  /** The REST state, when the server sent it along. */
  state: SessionState | null;
}

export interface StreamError {
  code: ErrorCode;
  codeName: string;
  message: string;
  requestId: number;
}

const STATUS_NAMES: Record<number, SessionStatusName> = {
  [SessionStatus.Paused]: 'paused',
  [SessionStatus.Playing]: 'playing',
  [SessionStatus.Stepping]: 'stepping',
  [SessionStatus.Error]: 'error',
};

export interface StreamOptions {
  /** ws(s)://host:port; default: the page's origin. */
  origin?: string;
  token?: string | null;
  /** Frames per wall second at most (0: no limit). */
  maxFrameRate?: number;
  layers?: Layer;
  /** Backoff of the first reconnection attempt, ms (doubles up to maxBackoffMs). */
  backoffMs?: number;
  maxBackoffMs?: number;
}

export class Stream {
  readonly frame = new Signal<FrameInfo>();
  readonly state = new Signal<StreamState>();
  readonly ack = new Signal<{ editId: number; frame: number }>();
  readonly error = new Signal<StreamError>();
  readonly connection = new Signal<{ status: ConnectionStatus; attempt: number; retryInMs: number }>();

  status: ConnectionStatus = 'closed';
  /** Messages received, and frames among them (for tests and the stats overlay). */
  messages = 0;
  frames = 0;

  private ws: WebSocket | null = null;
  private closedByUs = false;
  private attempt = 0;
  private retryTimer: ReturnType<typeof setTimeout> | null = null;
  private nextRequestId = 1;
  private readonly envelope = new Envelope();
  private readonly frameTable = new Frame();
  private readonly stateTable = new StateChange();
  private readonly ackTable = new Ack();
  private readonly errorTable = new WireError();
  private maxFrameRate: number;
  private layers: Layer;

  constructor(
    readonly sessionId: string,
    private readonly decoder: FrameDecoder,
    private readonly options: StreamOptions = {},
  ) {
    this.maxFrameRate = options.maxFrameRate ?? 0;
    this.layers = options.layers ?? Layer.Instances;
  }

  get url(): string {
    const origin = this.options.origin ?? location.origin.replace(/^http/, 'ws');
    return `${origin}/api/sessions/${encodeURIComponent(this.sessionId)}/stream`;
  }

  connect(): void {
    this.closedByUs = false;
    this.open();
  }

  /** Closes for good (no reconnection). */
  close(): void {
    this.closedByUs = true;
    if (this.retryTimer) clearTimeout(this.retryTimer);
    this.retryTimer = null;
    if (this.ws) {
      this.ws.onclose = this.ws.onmessage = this.ws.onerror = this.ws.onopen = null;
      this.ws.close();
      this.ws = null;
    }
    this.setStatus('closed', 0);
  }

  /** Replaces the subscription (frame-rate limit and optional layers); kept across reconnections. */
  subscribe(maxFrameRate: number, layers: Layer): number {
    this.maxFrameRate = maxFrameRate;
    this.layers = layers;
    return this.sendSubscribe();
  }

  /** Sends a Transport command; returns its request id (echoed by the StateChange or Error). */
  transport(command: TransportCommand, args: { steps?: number; frame?: number; speed?: number; until?: number } = {}): number {
    const b = new flatbuffers.Builder(64);
    const id = this.nextRequestId++;
    const t = Transport.createTransport(b, id, command, args.steps ?? null, args.frame ?? null, args.speed ?? null, args.until ?? null);
    this.send(b, Message.Transport, t);
    return id;
  }

  /** Sends an edit (the REST edit object); returns its id (echoed by Ack or Error). */
  edit(json: object): number {
    const b = new flatbuffers.Builder(256);
    const id = this.nextRequestId++;
    const s = b.createString(JSON.stringify(json));
    const e = Edit.createEdit(b, id, s);
    this.send(b, Message.Edit, e);
    return id;
  }

  private sendSubscribe(): number {
    const b = new flatbuffers.Builder(64);
    const id = this.nextRequestId++;
    const s = Subscribe.createSubscribe(b, id, this.maxFrameRate, this.layers);
    this.send(b, Message.Subscribe, s);
    return id;
  }

  private send(b: flatbuffers.Builder, type: Message, offset: flatbuffers.Offset) {
    const env = Envelope.createEnvelope(b, type, offset);
    Envelope.finishEnvelopeBuffer(b, env);
    if (!this.ws || this.ws.readyState !== WebSocket.OPEN) {
      throw new Error('the stream is not connected');
    }
    this.ws.send(b.asUint8Array() as Uint8Array<ArrayBuffer>);
  }

  private open() {
    this.setStatus(this.attempt === 0 ? 'connecting' : 'reconnecting', 0);
    const protocols = this.options.token ? [`flowclip-token.${this.options.token}`] : undefined;
    let ws: WebSocket;
    try {
      ws = new WebSocket(this.url, protocols);
    } catch (e) {
      this.error.dispatch({ code: ErrorCode.Internal, codeName: 'Internal', message: `stream: ${String(e)}`, requestId: 0 });
      this.scheduleReconnect();
      return;
    }
    ws.binaryType = 'arraybuffer';
    this.ws = ws;
    ws.onopen = () => {
      this.attempt = 0;
      this.setStatus('open', 0);
      if (this.maxFrameRate !== 0 || this.layers !== Layer.Instances) this.sendSubscribe();
    };
    ws.onmessage = (ev: MessageEvent) => this.onMessage(ev.data);
    ws.onclose = () => {
      this.ws = null;
      if (!this.closedByUs) this.scheduleReconnect();
    };
    ws.onerror = () => {
      // onclose follows; the reconnection reports the loss.
    };
  }

  private scheduleReconnect() {
    const base = this.options.backoffMs ?? 250;
    const max = this.options.maxBackoffMs ?? 5000;
    const delay = Math.min(max, base * 2 ** this.attempt) * (0.8 + 0.4 * Math.random());
    this.attempt++;
    this.setStatus('reconnecting', delay);
    this.retryTimer = setTimeout(() => {
      this.retryTimer = null;
      if (!this.closedByUs) this.open();
    }, delay);
  }

  private setStatus(status: ConnectionStatus, retryInMs: number) {
    this.status = status;
    this.connection.dispatch({ status, attempt: this.attempt, retryInMs });
  }

  private onMessage(data: unknown) {
    this.messages++;
    if (!(data instanceof ArrayBuffer)) {
      this.error.dispatch({ code: ErrorCode.InvalidMessage, codeName: 'InvalidMessage', message: 'stream: a text message from the server', requestId: 0 });
      return;
    }
    const bb = new flatbuffers.ByteBuffer(new Uint8Array(data));
    if (data.byteLength < 8 || !Envelope.bufferHasIdentifier(bb)) {
      this.error.dispatch({ code: ErrorCode.InvalidMessage, codeName: 'InvalidMessage', message: 'stream: a message without the FCW1 identifier', requestId: 0 });
      return;
    }
    try {
      const env = Envelope.getRootAsEnvelope(bb, this.envelope);
      switch (env.messageType()) {
        case Message.Frame: {
          const frame = env.message(this.frameTable) as Frame;
          this.frames++;
          this.frame.dispatch(this.decoder.decode(frame, data.byteLength));
          break;
        }
        case Message.StateChange:
          this.state.dispatch(readState(env.message(this.stateTable) as StateChange));
          break;
        case Message.Ack: {
          const a = env.message(this.ackTable) as Ack;
          this.ack.dispatch({ editId: a.editId(), frame: a.frame() });
          break;
        }
        case Message.Error: {
          const e = env.message(this.errorTable) as WireError;
          this.error.dispatch({
            code: e.code(),
            codeName: ErrorCode[e.code()] ?? String(e.code()),
            message: e.message() ?? '(no message)',
            requestId: e.requestId(),
          });
          break;
        }
        default:
          this.error.dispatch({ code: ErrorCode.UnsupportedMessage, codeName: 'UnsupportedMessage', message: `stream: unexpected message type ${env.messageType()}`, requestId: 0 });
      }
    } catch (e) {
      this.error.dispatch({ code: ErrorCode.InvalidMessage, codeName: 'InvalidMessage', message: `stream: a message could not be decoded: ${e instanceof Error ? e.message : String(e)}`, requestId: 0 });
    }
  }
}

function readState(s: StateChange): StreamState {
  let state: SessionState | null = null;
  const json = s.stateJson();
  if (json) {
    try {
      state = JSON.parse(json) as SessionState;
    } catch {
      state = null;
    }
  }
  return {
    sessionId: s.sessionId() ?? '',
    status: STATUS_NAMES[s.status()] ?? 'paused',
    frame: s.frame(),
    time: s.time(),
    shownFrame: s.shownFrame(),
    live: s.live(),
    playbackSpeed: s.playbackSpeed(),
    historyFirst: s.historyFirstFrame(),
    historyLast: s.historyLastFrame(),
    historyDropped: s.historyDroppedFrames(),
    message: s.message() ?? '',
    requestId: s.requestId(),
    state,
  };
}
