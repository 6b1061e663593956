// Export dialog (toolbar "Export…"): the session's history meshed into the
// formats a DCC imports (POST /api/sessions/{id}/export with formats,
// docs/surfaces.md). The job's progress arrives on the stream (state
// "export") and fills the bar; a finished job lists its files to download.
// Listens to the editor's signals; acts only through the editor.
import type { Editor } from '../core/Editor';
import type { SurfaceJob } from '../net/types';
import { el } from './dom';
import { FormatChecks } from './FormatChecks';

const DEFAULT_FORMATS = new Set(['vdb', 'ply']);

export class ExportDialog {
  readonly dom: HTMLDialogElement;
  private readonly name: HTMLInputElement;
  private readonly voxel: HTMLInputElement;
  private readonly formats: FormatChecks;
  private readonly start: HTMLButtonElement;
  private readonly cancel: HTMLButtonElement;
  private readonly bar: HTMLProgressElement;
  private readonly status: HTMLElement;
  private readonly files: HTMLElement;

  constructor(private readonly editor: Editor) {
    this.name = el('input', { testid: 'export-name', title: 'Export name: NAME.h5 and the directory NAME/ on the server', attrs: { type: 'text', size: '16', spellcheck: 'false' } });
    this.voxel = el('input', { testid: 'export-voxel', title: 'Surface voxel in particle radii (smaller: finer, slower)', attrs: { type: 'number', min: '0.1', max: '2', step: '0.05', value: '0.5' } });
    this.formats = new FormatChecks(editor, 'export', DEFAULT_FORMATS);
    this.start = el('button', { testid: 'export-start', text: 'Export', title: 'Write the history and mesh it into the formats checked', attrs: { type: 'button' } });
    this.cancel = el('button', { testid: 'export-cancel', text: 'Cancel export', title: 'Stop the export: nothing of it is kept', attrs: { type: 'button' } });
    const close = el('button', { testid: 'export-close', text: 'Close', attrs: { type: 'button' } });
    this.bar = el('progress', { testid: 'export-progress', attrs: { max: '1', value: '0' } });
    this.status = el('span', { testid: 'export-status', className: 'export-status' });
    this.files = el('ul', { testid: 'export-files', className: 'export-files' });
    this.dom = el('dialog', { className: 'export-dialog', testid: 'export-dialog' }, [
      el('h3', { text: 'Export surfaces' }),
      el('p', { className: 'hint', text: 'The recorded frames of this session, meshed for Houdini and Blender (OpenVDB, PLY, OBJ, USD).' }),
      el('label', { text: 'Name ' }, [this.name]),
      this.formats.dom,
      el('label', { text: 'Voxel (particle radii) ' }, [this.voxel]),
      el('div', { className: 'export-buttons' }, [this.start, this.cancel, close]),
      el('div', { className: 'export-progress' }, [this.bar, this.status]),
      this.files,
    ]);
    this.start.addEventListener('click', () => void this.submit());
    this.cancel.addEventListener('click', () => void editor.cancelExport());
    close.addEventListener('click', () => this.dom.close());
    editor.signals.sessionChanged.add((s) => {
      this.name.value = s ? `${s.scene}_shot` : '';
      this.show(editor.exportJob);
    });
    editor.signals.exportJobChanged.add((job) => this.show(job));
    editor.signals.exportRequested.add(() => this.open());
    this.show(null);
  }

  open() {
    if (!this.dom.open) this.dom.showModal();
  }

  private async submit() {
    const name = this.name.value.trim();
    if (!/^[A-Za-z0-9_-]{1,64}$/.test(name)) {
      this.editor.message('error', `export: "${name}" is not a name (letters, digits, _ and -, at most 64)`);
      return;
    }
    const formats = this.formats.checked();
    if (!formats.length) {
      this.editor.message('error', 'export: check at least one format');
      return;
    }
    const voxel = Number(this.voxel.value);
    await this.editor.exportSurfaces(name, formats, Number.isFinite(voxel) && voxel > 0 ? { voxel_size: voxel } : {}, true);
  }

  private show(job: SurfaceJob | null) {
    const active = job !== null && (job.state === 'queued' || job.state === 'running');
    this.start.disabled = active || !this.editor.session;
    this.cancel.disabled = !active;
    this.bar.value = job ? job.progress : 0;
    this.dom.dataset['state'] = job?.state ?? '';
    this.status.textContent = !job
      ? ''
      : job.state === 'done'
        ? `done: ${job.frames} frames, ${(job.bytes / 1e6).toFixed(1)} MB in ${job.elapsed_s.toFixed(1)} s`
        : job.state === 'failed'
          ? `failed: ${job.error ?? ''}`
          : job.state === 'cancelled'
            ? 'cancelled: nothing was kept'
            : `${job.state}: ${job.frames_done} / ${job.frames || '?'} frames`;
    if (job?.state !== 'done') {
      this.files.replaceChildren();
      return;
    }
    this.files.replaceChildren(
      ...(job.files ?? []).map((file) => {
        const a = el('a', { text: file, testid: `export-file-${file}`, attrs: { href: '#' } });
        a.addEventListener('click', (e) => {
          e.preventDefault();
          void this.download(job.name, file);
        });
        return el('li', {}, [a]);
      }),
    );
  }

  private async download(name: string, file: string) {
    try {
      const blob = await this.editor.api.exportFile(name, file);
      const a = el('a', { attrs: { href: URL.createObjectURL(blob), download: file } });
      document.body.append(a);
      a.click();
      a.remove();
      setTimeout(() => URL.revokeObjectURL(a.href), 10_000);
    } catch (e) {
      this.editor.reportError(e, `download ${file}`);
    }
  }
}
