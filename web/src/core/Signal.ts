// A typed signal: listeners added to it are called, in order, with each
// dispatched value (the three.js editor's signals, without a dependency).
export type Listener<T> = (value: T) => void;

export class Signal<T = void> {
  private listeners: Listener<T>[] = [];

  /** Adds a listener; returns a function that removes it. */
  add(listener: Listener<T>): () => void {
    // Copy on write, so that a listener may add or remove during a dispatch.
    this.listeners = [...this.listeners, listener];
    return () => this.remove(listener);
  }

  remove(listener: Listener<T>): void {
    this.listeners = this.listeners.filter((l) => l !== listener);
  }

  dispatch(value: T): void {
    const listeners = this.listeners;
    for (let i = 0; i < listeners.length; i++) listeners[i]!(value);
  }

  get size(): number {
    return this.listeners.length;
  }
}
