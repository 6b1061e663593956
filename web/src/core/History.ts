// One undo/redo history for the editor. Commands run one at a time, in the
// order they were issued (execute, undo and redo are queued), so that an undo
// pressed while a PATCH is in flight undoes it after it lands.
import { Command } from './Command';
import { Signal } from './Signal';

export interface HistoryEntry {
  readonly id: number;
  readonly name: string;
}

export class History {
  readonly changed = new Signal<void>();
  /** A command failed (its execute or undo threw); the history skips it. */
  readonly failed = new Signal<{ command: Command; error: unknown; phase: 'execute' | 'undo' | 'redo' }>();
  /** Commands issued within this time of the previous one with the same mergeKey merge. */
  mergeWindowMs = 500;

  private undos: Command[] = [];
  private redos: Command[] = [];
  private queue: Promise<void> = Promise.resolve();
  private pending = 0;
  /** Bumped by clear(): commands queued before it do not run or record. */
  private epoch = 0;

  get canUndo(): boolean {
    return this.undos.length > 0;
  }
  get canRedo(): boolean {
    return this.redos.length > 0;
  }
  get undoEntries(): HistoryEntry[] {
    return this.undos.map((c) => ({ id: c.id, name: c.name }));
  }
  get redoEntries(): HistoryEntry[] {
    return this.redos.map((c) => ({ id: c.id, name: c.name }));
  }
  /** Commands queued or running. */
  get busy(): boolean {
    return this.pending > 0;
  }

  /** Executes `cmd` and records it (merged into the last entry when it may). */
  execute(cmd: Command): Promise<void> {
    const epoch = this.epoch;
    return this.enqueue(async () => {
      if (epoch !== this.epoch) return; // queued before clear(): another document
      // Whether it merges is decided when it runs (in order), so that an
      // undo issued between two commands of one drag ends the merge.
      const last = this.undos[this.undos.length - 1];
      const merges =
        last !== undefined &&
        cmd.mergeKey !== null &&
        last.mergeKey === cmd.mergeKey &&
        cmd.createdAt - last.createdAt < (cmd.mergeWindowMs ?? this.mergeWindowMs);
      try {
        await cmd.execute();
      } catch (error) {
        this.failed.dispatch({ command: cmd, error, phase: 'execute' });
        return;
      }
      if (epoch !== this.epoch) return;
      if (merges && this.undos[this.undos.length - 1] === last) {
        last.merge(cmd);
        last.createdAt = cmd.createdAt;
      } else {
        this.undos.push(cmd);
      }
      this.redos = [];
      this.changed.dispatch();
    });
  }

  undo(): Promise<void> {
    const epoch = this.epoch;
    return this.enqueue(async () => {
      if (epoch !== this.epoch) return;
      const cmd = this.undos.pop();
      if (!cmd) return;
      try {
        await cmd.undo();
        if (epoch === this.epoch) this.redos.push(cmd);
      } catch (error) {
        // The server refused to restore: keep the command where it was.
        this.undos.push(cmd);
        this.failed.dispatch({ command: cmd, error, phase: 'undo' });
      }
      this.changed.dispatch();
    });
  }

  redo(): Promise<void> {
    const epoch = this.epoch;
    return this.enqueue(async () => {
      if (epoch !== this.epoch) return;
      const cmd = this.redos.pop();
      if (!cmd) return;
      try {
        await cmd.execute();
        if (epoch === this.epoch) this.undos.push(cmd);
      } catch (error) {
        this.redos.push(cmd);
        this.failed.dispatch({ command: cmd, error, phase: 'redo' });
      }
      this.changed.dispatch();
    });
  }

  /** Forgets every command (a new scene or session). */
  clear(): void {
    this.epoch++;
    this.undos = [];
    this.redos = [];
    this.changed.dispatch();
  }

  /** Resolves when every queued command has run. */
  idle(): Promise<void> {
    return this.queue;
  }

  private enqueue(task: () => Promise<void>): Promise<void> {
    this.pending++;
    const run = this.queue.then(task).finally(() => {
      this.pending--;
    });
    this.queue = run.catch(() => undefined);
    return run;
  }
}
