// Editor shortcuts: Ctrl+Z undo, Ctrl+Shift+Z / Ctrl+Y redo (Cmd on macOS),
// Space play/pause; not while typing in a field.
import type { Editor } from '../core/Editor';

export function installKeyboard(editor: Editor, target: Window = window) {
  target.addEventListener('keydown', (e: KeyboardEvent) => {
    const t = e.target as HTMLElement | null;
    if (t && (t.tagName === 'INPUT' || t.tagName === 'TEXTAREA' || t.tagName === 'SELECT' || t.isContentEditable)) return;
    const mod = e.ctrlKey || e.metaKey;
    const key = e.key.toLowerCase();
    if (mod && key === 'z') {
      e.preventDefault();
      void (e.shiftKey ? editor.redo() : editor.undo());
    } else if (mod && key === 'y') {
      e.preventDefault();
      void editor.redo();
    } else if (!mod && e.key === ' ' && editor.session && t?.tagName !== 'BUTTON') {
      e.preventDefault();
      void editor.transport(editor.view.status === 'playing' ? 'pause' : 'play');
    }
  });
}
