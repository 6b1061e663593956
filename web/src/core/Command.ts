// A change of the editor's document, undoable (the three.js editor's
// Command): execute() applies it (on the server when it changes server state)
// and undo() restores what it replaced. Both may be asynchronous; History
// runs them one at a time, in order.
let nextId = 1;

export abstract class Command {
  readonly id = nextId++;
  /** Shown in the history, e.g. "Move drop". */
  abstract readonly name: string;
  /**
   * Commands of the same `mergeKey` issued in quick succession (a gizmo drag,
   * typing in a field) merge into one history entry: the first one's old
   * value and the last one's new value. null: never merges.
   */
  readonly mergeKey: string | null = null;
  /**
   * How long after the previous command a merge may happen (ms); null: the
   * history's default (0.5 s). A gizmo drag uses a mergeKey unique to the drag
   * and Infinity, so that a slow drag is still one entry.
   */
  readonly mergeWindowMs: number | null = null;
  /** Wall time it was created (ms), for merging. */
  createdAt = performance.now();

  abstract execute(): Promise<void>;
  abstract undo(): Promise<void>;

  /** Takes `newer`'s new value (only called when mergeKey matches). */
  merge(_newer: Command): void {
    throw new Error(`${this.name} cannot merge`);
  }
}
