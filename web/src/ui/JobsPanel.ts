// Render jobs panel (left sidebar, collapsible): the session's render jobs as
// its state lists them ("jobs", on the stream), newest on top: name, state,
// where they run, the job's progress and a bar per task labelled with its
// wedge value; Cancel while queued or running; a done task's files to
// download. Each job's row is updated in place, so the bars move instead of
// being rebuilt. Listens to the editor's signals; acts only through the editor.
import type { Editor } from '../core/Editor';
import type { RenderJob, RenderTask } from '../net/types';
import { el } from './dom';

/** Files shown before "more": the ones a user opens first. */
const FIRST_FILES = ['stats.json', 'frames.h5'];
const FILES_SHOWN = 4;

/** The task's wedge value as "key = value" (its key shortened to the last part), or its number. */
function taskLabel(task: RenderTask, index: number): string {
  const entries = Object.entries(task.overrides ?? {});
  if (!entries.length) return `task ${index + 1}`;
  return entries.map(([k, v]) => `${k.replace(/^instances\[([^\]]+)\]\./, '$1 ')} = ${JSON.stringify(v)}`).join(', ');
}

/** The files in the order a user looks for them: stats and particles first, then surfaces, then the rest. */
function orderFiles(files: readonly string[]): string[] {
  const rank = (f: string) => (FIRST_FILES.includes(f) ? FIRST_FILES.indexOf(f) : f.startsWith('surface/') ? FIRST_FILES.length : FIRST_FILES.length + 1);
  return [...files].sort((a, b) => rank(a) - rank(b) || a.localeCompare(b, 'en', { numeric: true }));
}

class TaskRow {
  readonly dom: HTMLElement;
  private readonly label: HTMLElement;
  private readonly bar: HTMLProgressElement;
  private readonly text: HTMLElement;
  private readonly files: HTMLElement;
  private filesShown = false;

  constructor(private readonly editor: Editor, private readonly jobId: string, private readonly index: number) {
    const id = `${jobId}-${index}`;
    this.label = el('span', { className: 'task-label', testid: `job-task-label-${id}` });
    this.bar = el('progress', { testid: `job-task-${id}`, attrs: { max: '1', value: '0' } });
    this.text = el('span', { className: 'task-text', testid: `job-task-text-${id}` });
    this.files = el('ul', { className: 'export-files job-files', testid: `job-files-${id}` });
    this.dom = el('div', { className: 'job-task' }, [el('div', { className: 'task-head' }, [this.label, this.text]), this.bar, this.files]);
  }

  update(job: RenderJob, task: RenderTask) {
    this.label.textContent = taskLabel(task, this.index);
    this.label.title = this.label.textContent;
    // A task of a cancelled or failed job stops where it was.
    const state = task.state !== 'done' && (job.state === 'cancelled' || job.state === 'failed') ? job.state : task.state;
    this.bar.dataset['state'] = state;
    this.bar.max = Math.max(1, task.frames);
    this.bar.value = task.state === 'done' ? this.bar.max : task.frame;
    this.bar.dataset['progress'] = String(task.frames > 0 ? task.frame / task.frames : 0);
    this.text.textContent = task.frames > 0 ? `${task.frame}/${task.frames}` : state;
    if (task.state === 'done' && task.files && !this.filesShown) this.showFiles(job, task, task.files);
  }

  /** Built once: a done task's files do not change (and "more" stays as the user left it). */
  private showFiles(job: RenderJob, task: RenderTask, files: readonly string[]) {
    this.filesShown = true;
    const ordered = orderFiles(files);
    const item = (file: string, hidden: boolean) => {
      const a = el('a', { text: file, testid: `job-file-${this.jobId}-${this.index}-${file}`, title: `Download ${file} of task ${task.id}`, attrs: { href: '#' } });
      a.addEventListener('click', (e) => {
        e.preventDefault();
        void this.download(job.name, task.id, file);
      });
      const li = el('li', {}, [a]);
      li.hidden = hidden;
      return li;
    };
    const items = ordered.map((f, i) => item(f, i >= FILES_SHOWN));
    this.files.replaceChildren(...items);
    const more = ordered.length - FILES_SHOWN;
    if (more > 0) {
      const toggle = el('button', { className: 'link', testid: `job-files-more-${this.jobId}-${this.index}`, text: `${more} more…`, attrs: { type: 'button' } });
      toggle.addEventListener('click', () => {
        const open = toggle.dataset['open'] !== 'true';
        toggle.dataset['open'] = String(open);
        toggle.textContent = open ? 'fewer' : `${more} more…`;
        items.forEach((li, i) => (li.hidden = !open && i >= FILES_SHOWN));
      });
      this.files.append(el('li', {}, [toggle]));
    }
  }

  private async download(jobName: string, task: string, file: string) {
    const blob = await this.editor.renderJobFile(this.jobId, task, file);
    if (!blob) return;
    const a = el('a', { attrs: { href: URL.createObjectURL(blob), download: `${jobName}_${task}_${file.replace(/\//g, '_')}` } });
    document.body.append(a);
    a.click();
    a.remove();
    setTimeout(() => URL.revokeObjectURL(a.href), 10_000);
  }
}

class JobRow {
  readonly dom: HTMLElement;
  private readonly state: HTMLElement;
  private readonly bar: HTMLProgressElement;
  private readonly summary: HTMLElement;
  private readonly cancel: HTMLButtonElement;
  private readonly error: HTMLElement;
  private readonly tasksDom: HTMLElement;
  private readonly tasks: TaskRow[] = [];
  private readonly where: HTMLElement;

  constructor(private readonly editor: Editor, readonly id: string) {
    this.state = el('span', { className: 'job-state', testid: `job-state-${id}` });
    this.where = el('span', { className: 'job-where', testid: `job-where-${id}` });
    this.bar = el('progress', { testid: `job-progress-${id}`, attrs: { max: '1', value: '0' } });
    this.summary = el('span', { className: 'job-summary', testid: `job-summary-${id}` });
    this.cancel = el('button', { testid: `job-cancel-${id}`, text: 'Cancel', title: 'Stop the job: its processes are killed and nothing of it is kept', attrs: { type: 'button' } });
    this.error = el('div', { className: 'job-error', testid: `job-error-${id}` });
    this.tasksDom = el('div', { className: 'job-tasks', testid: `job-tasks-${id}` });
    this.cancel.addEventListener('click', () => void editor.cancelRender(id));
    this.dom = el('div', { className: 'job', testid: `job-${id}` }, [
      el('div', { className: 'job-head' }, [el('span', { className: 'job-name', testid: `job-name-${id}` }), this.state, this.cancel]),
      this.where,
      el('div', { className: 'job-bar' }, [this.bar, this.summary]),
      this.error,
      this.tasksDom,
    ]);
  }

  update(job: RenderJob, where: string) {
    this.dom.dataset['state'] = job.state;
    this.dom.querySelector('.job-name')!.textContent = job.name;
    this.state.textContent = job.cancel_requested && (job.state === 'queued' || job.state === 'running') ? 'cancelling…' : job.state;
    this.state.dataset['value'] = job.state;
    this.where.textContent = where ? `on ${where}` : '';
    this.bar.value = job.progress;
    this.summary.textContent = `${job.frames_done}/${job.frames || '?'} frames · ${job.tasks_done}/${job.tasks.length} tasks · ${job.elapsed_s.toFixed(1)} s`;
    this.cancel.hidden = job.state !== 'queued' && job.state !== 'running';
    this.cancel.disabled = job.cancel_requested;
    this.error.textContent = job.state === 'failed' ? (job.error ?? 'failed') : job.state === 'cancelled' ? 'cancelled: nothing was kept' : '';
    job.tasks.forEach((task, i) => {
      let row = this.tasks[i];
      if (!row) {
        row = new TaskRow(this.editor, this.id, i);
        this.tasks.push(row);
        this.tasksDom.append(row.dom);
      }
      row.update(job, task);
    });
  }
}

export class JobsPanel {
  readonly dom: HTMLElement;
  private readonly list: HTMLElement;
  private readonly empty: HTMLElement;
  private readonly count: HTMLElement;
  private readonly toggle: HTMLButtonElement;
  private readonly rows = new Map<string, JobRow>();

  constructor(private readonly editor: Editor) {
    this.count = el('span', { className: 'count', testid: 'jobs-count' });
    this.toggle = el('button', { className: 'link', testid: 'jobs-toggle', title: 'Show or hide the render jobs', attrs: { type: 'button', 'aria-expanded': 'true' } });
    this.empty = el('div', { className: 'empty', testid: 'jobs-empty' });
    this.list = el('div', { className: 'jobs-list', testid: 'jobs-list' });
    this.dom = el('section', { className: 'panel jobs', testid: 'jobs-panel' }, [
      el('h2', {}, [this.toggle, 'Render jobs', this.count]),
      this.empty,
      this.list,
    ]);
    this.toggle.addEventListener('click', () => this.setOpen(this.dom.classList.contains('collapsed')));
    editor.signals.renderJobsChanged.add((jobs) => this.show(jobs));
    editor.signals.renderAvailabilityChanged.add(() => this.show(editor.renderJobs));
    editor.signals.sessionChanged.add(() => this.show(editor.renderJobs));
    this.setOpen(true);
    this.show(editor.renderJobs);
  }

  private setOpen(open: boolean) {
    this.dom.classList.toggle('collapsed', !open);
    this.toggle.textContent = open ? '▾' : '▸';
    this.toggle.setAttribute('aria-expanded', String(open));
  }

  private show(jobs: readonly RenderJob[]) {
    const a = this.editor.renderAvailability;
    // A job this editor has not shown yet opens the panel.
    if (jobs.some((j) => !this.rows.has(j.id))) this.setOpen(true);
    const ids = new Set(jobs.map((j) => j.id));
    for (const [id, row] of this.rows) {
      if (!ids.has(id)) {
        row.dom.remove();
        this.rows.delete(id);
      }
    }
    // Newest on top (the state lists them oldest first).
    const order = [...jobs].reverse().map((job) => {
      let row = this.rows.get(job.id);
      if (!row) {
        row = new JobRow(this.editor, job.id);
        this.rows.set(job.id, row);
      }
      row.update(job, a.where);
      return row.dom;
    });
    // Moved only when the order changed: a link under the pointer stays put.
    const children = [...this.list.children];
    if (children.length !== order.length || order.some((d, i) => children[i] !== d)) this.list.replaceChildren(...order);
    this.count.textContent = jobs.length ? `(${jobs.length})` : '';
    this.empty.textContent = jobs.length
      ? ''
      : !this.editor.session
        ? 'No session open.'
        : a.known && !a.available
          ? a.reason
          : 'None for this session: Render final… in the toolbar runs its scene again, finer, as files.';
    this.empty.hidden = jobs.length > 0;
  }
}
