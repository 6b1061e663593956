// Editor shortcuts (Blender's where it has one), not while typing in a text
// field: Space play/pause (also with a checkbox or button focused, which then
// does not toggle), Ctrl+Z undo, Ctrl+Shift+Z / Ctrl+Y redo, Ctrl+S save
// (Cmd on macOS), Delete / Backspace remove the selected instance, F frame
// it, Home / End the play range's start / end, Left / Right a frame back /
// on, Up / Down the next / previous key.
import type { Editor } from '../core/Editor';
import { RemoveInstanceCommand } from '../commands/RemoveInstanceCommand';

/** Elements where keys are text (Space, arrows and Delete belong to them). */
function typing(t: HTMLElement | null): boolean {
  if (!t) return false;
  if (t.isContentEditable || t.tagName === 'TEXTAREA' || t.tagName === 'SELECT') return true;
  if (t.tagName !== 'INPUT') return false;
  const type = (t as HTMLInputElement).type;
  return type !== 'checkbox' && type !== 'radio' && type !== 'button' && type !== 'range';
}

/** A focused control that Space would activate on its own (checkbox, button). */
function activatable(t: HTMLElement | null): boolean {
  return !!t && (t.tagName === 'BUTTON' || t.tagName === 'INPUT');
}

export function installKeyboard(editor: Editor, target: Window = window) {
  target.addEventListener('keydown', (e: KeyboardEvent) => {
    const t = e.target as HTMLElement | null;
    const mod = e.ctrlKey || e.metaKey;
    const key = e.key.toLowerCase();
    const handled = () => e.preventDefault();
    // Save works from anywhere, a text field included (the browser's "save page" never).
    if (mod && key === 's' && !e.shiftKey && !e.altKey) {
      handled();
      editor.signals.saveRequested.dispatch();
      return;
    }
    if (typing(t)) return;
    if (mod && key === 'z') {
      handled();
      void (e.shiftKey ? editor.redo() : editor.undo());
    } else if (mod && key === 'y') {
      handled();
      void editor.redo();
    } else if (mod || e.altKey) {
      return;
    } else if (e.key === ' ') {
      handled(); // a focused checkbox or button is not toggled or clicked
      if (!e.repeat && editor.session) void editor.togglePlay();
    } else if ((e.key === 'Delete' || e.key === 'Backspace') && editor.selected) {
      handled();
      void editor.execute(new RemoveInstanceCommand(editor, editor.selected));
    } else if (key === 'f' && !e.shiftKey) {
      handled();
      editor.signals.frameSelectionRequested.dispatch();
    } else if (e.key === 'Home' && editor.session) {
      handled();
      editor.setPlayhead(editor.rangeFrames().start);
    } else if (e.key === 'End' && editor.session) {
      handled();
      editor.setPlayhead(editor.rangeFrames().end);
    } else if ((e.key === 'ArrowLeft' || e.key === 'ArrowRight') && editor.session) {
      handled();
      editor.setPlayhead(editor.playheadFrame + (e.key === 'ArrowRight' ? 1 : -1));
    } else if ((e.key === 'ArrowUp' || e.key === 'ArrowDown') && editor.session) {
      handled();
      editor.jumpToKey(e.key === 'ArrowUp' ? 1 : -1);
    }
  });
  // Space activates a focused checkbox or button on key-up: not when it played or paused.
  target.addEventListener('keyup', (e: KeyboardEvent) => {
    const t = e.target as HTMLElement | null;
    if (e.key === ' ' && !typing(t) && activatable(t)) e.preventDefault();
  });
}
