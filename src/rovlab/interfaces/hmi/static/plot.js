// rovlab HMI: a small strip-chart module on <canvas> (no dependencies).
//
// A StripChart shows the last `window` seconds of a few series against time. Series kinds:
//   line  - a polyline (gaps where a value is missing)
//   dots  - one small square per sample (measurements)
//   step  - a staircase (references)
//   band  - a filled region between lo and hi (e.g. estimate +/- 2 sigma)
// Samples go into fixed-size ring buffers (push is O(1), no allocation); draw() renders the
// visible part with an automatic y range. Call draw() from requestAnimationFrame.
//
// An angle (option period, e.g. 360 for a heading in degrees) is drawn unwrapped about the
// circular mean of the visible samples: every sample is shown as the value nearest that centre
// (a heading dithering about +-180 deg is one line near 180, not a 360 deg step and a chart
// spanning -180..180), tick labels are the wrapped angles (..., 170, 180, -170, ...), and where a
// series still passes the far side (a full turn) its line leaves the plot at one edge and comes
// back at the other, never drawn across it. The same mapping holds for every series of the
// chart (truth, estimate and its band, measurements, reference).
"use strict";

(function (global) {
  const FONT = '11px system-ui, -apple-system, "Segoe UI", Roboto, "DejaVu Sans", Arial, sans-serif';
  const TITLE_FONT = '600 12px system-ui, -apple-system, "Segoe UI", Roboto, "DejaVu Sans", Arial, sans-serif';

  class Ring {
    constructor(capacity, width) {
      this.capacity = capacity;
      this.width = width; // values per sample besides time
      this.t = new Float64Array(capacity);
      this.v = new Float64Array(capacity * width);
      this.start = 0;
      this.length = 0;
    }
    push(t, a, b) {
      let i;
      if (this.length < this.capacity) {
        i = (this.start + this.length) % this.capacity;
        this.length++;
      } else {
        i = this.start;
        this.start = (this.start + 1) % this.capacity;
      }
      this.t[i] = t;
      this.v[i * this.width] = a;
      if (this.width > 1) this.v[i * this.width + 1] = b;
    }
    clear() { this.start = 0; this.length = 0; }
    index(k) { return (this.start + k) % this.capacity; }
    // first logical index with t >= t0 (binary search; times are non-decreasing)
    lowerBound(t0) {
      let lo = 0, hi = this.length;
      while (lo < hi) {
        const mid = (lo + hi) >> 1;
        if (this.t[this.index(mid)] < t0) lo = mid + 1; else hi = mid;
      }
      return lo;
    }
    lastTime() { return this.length ? this.t[this.index(this.length - 1)] : NaN; }
  }

  class Series {
    constructor(opts) {
      this.name = opts.name;
      this.label = opts.label || opts.name;
      this.kind = opts.kind || "line";
      this.color = opts.color || "#333";
      this.fill = opts.fill || "rgba(0,0,0,0.12)";
      this.width = opts.width || 1.5;
      this.dash = opts.dash || null;
      this.legend = opts.legend !== false;
      this.ring = new Ring(opts.capacity || 4096, this.kind === "band" ? 2 : 1);
    }
    push(t, y) { this.ring.push(t, y, 0); }
    pushBand(t, lo, hi) { this.ring.push(t, lo, hi); }
    clear() { this.ring.clear(); }
  }

  function niceStep(span, target) {
    const raw = span / Math.max(1, target);
    const mag = Math.pow(10, Math.floor(Math.log10(raw)));
    const n = raw / mag;
    return (n < 1.5 ? 1 : n < 3 ? 2 : n < 7 ? 5 : 10) * mag;
  }

  function fmt(v, step) {
    if (v === 0) return "0";
    const a = Math.abs(v);
    if (a >= 1e5 || a < 1e-3) return v.toExponential(1);
    const digits = Math.max(0, Math.min(6, -Math.floor(Math.log10(step) + 1e-9)));
    return v.toFixed(digits);
  }

  class StripChart {
    constructor(canvas, opts) {
      this.canvas = canvas;
      this.ctx = canvas.getContext("2d");
      this.title = opts.title || "";
      this.unit = opts.unit || "";
      this.window = opts.window || 60;
      this.minSpan = opts.minSpan || 1e-9;
      this.period = opts.period || 0; // an angle's period (360 for degrees); 0: not an angle
      this.center = 0; // the period's centre used in the last draw (see unwrap)
      this.series = [];
      this.byName = {};
      this.now = 0;
      this.dirty = true;
      this.cssWidth = 0;
      this.cssHeight = 0;
      this.view = null; // what the last draw showed: {t0, t1, y0, y1, center, breaks} (tests read it)
      this.breaks = 0;
    }
    // an angle as drawn: the value nearest this.center (identity when the chart is not an angle)
    unwrap(v) {
      const P = this.period;
      return P ? v - P * Math.round((v - this.center) / P) : v;
    }
    // fn(ring, i) for every sample within [t0, t1] of the bands (bands true) or of the other series
    forVisible(t0, t1, bands, fn) {
      for (const s of this.series) {
        if ((s.kind === "band") !== bands) continue;
        const r = s.ring;
        for (let k = r.lowerBound(t0); k < r.length; k++) {
          const i = r.index(k);
          if (r.t[i] > t1) break;
          fn(r, i);
        }
      }
    }
    // the circular mean of the visible samples (the band's middles if there is nothing else)
    circularCenter(t0, t1) {
      const P = this.period;
      let sx = 0, sy = 0, n = 0;
      for (const bands of [false, true]) {
        this.forVisible(t0, t1, bands, (r, i) => {
          const v = r.width > 1 ? 0.5 * (r.v[i * 2] + r.v[i * 2 + 1]) : r.v[i];
          const a = 2 * Math.PI * v / P;
          sx += Math.cos(a); sy += Math.sin(a); n++;
        });
        if (n) break;
      }
      return n && (sx * sx + sy * sy) > 1e-18 ? Math.atan2(sy, sx) * P / (2 * Math.PI) : this.center;
    }
    tickLabel(v) {  // an angle's tick label: wrapped into (-P/2, P/2]
      const P = this.period;
      return P ? v - P * Math.ceil((v - P / 2) / P - 1e-12) : v;
    }
    add(opts) {
      const s = new Series(opts);
      this.series.push(s);
      this.byName[s.name] = s;
      this.dirty = true;
      return s;
    }
    get(name) { return this.byName[name]; }
    push(name, t, y) {
      const s = this.byName[name];
      if (s === undefined || y === null || y === undefined || !isFinite(y)) return;
      s.push(t, y);
      if (t > this.now) this.now = t;
      this.dirty = true;
    }
    pushBand(name, t, lo, hi) {
      const s = this.byName[name];
      if (s === undefined || !isFinite(lo) || !isFinite(hi)) return;
      s.pushBand(t, lo, hi);
      if (t > this.now) this.now = t;
      this.dirty = true;
    }
    clear() {
      for (const s of this.series) s.clear();
      this.now = 0;
      this.dirty = true;
    }
    resize() {
      const dpr = global.devicePixelRatio || 1;
      const w = this.canvas.clientWidth, h = this.canvas.clientHeight;
      if (w === 0 || h === 0) return false;
      if (w !== this.cssWidth || h !== this.cssHeight || this.canvas.width !== Math.round(w * dpr)) {
        this.cssWidth = w;
        this.cssHeight = h;
        this.canvas.width = Math.round(w * dpr);
        this.canvas.height = Math.round(h * dpr);
        this.dirty = true;
      }
      this.ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
      return true;
    }
    extent(t0, t1, bands) {
      let lo = Infinity, hi = -Infinity;
      this.forVisible(t0, t1, bands, (r, i) => {
        if (r.width > 1) {  // a band: its middle unwrapped, its width kept
          const a = r.v[2 * i], b = r.v[2 * i + 1], m = this.unwrap(0.5 * (a + b)), h = 0.5 * (b - a);
          if (m - h < lo) lo = m - h;
          if (m + h > hi) hi = m + h;
        } else {
          const v = this.unwrap(r.v[i]);
          if (v < lo) lo = v;
          if (v > hi) hi = v;
        }
      });
      return [lo, hi];
    }
    yRange(t0, t1) {
      // fit the lines and dots; a band (e.g. +/- 2 sigma while dead-reckoning) may widen the range
      // by at most the data's own span on each side, so it never squashes the estimate flat
      let [lo, hi] = this.extent(t0, t1, false);
      const [blo, bhi] = this.extent(t0, t1, true);
      if (!isFinite(lo)) { lo = blo; hi = bhi; }
      if (!isFinite(lo)) { lo = -1; hi = 1; }
      let span = Math.max(hi - lo, this.minSpan);
      if (isFinite(blo)) {
        lo = Math.min(lo, Math.max(blo, lo - span));
        hi = Math.max(hi, Math.min(bhi, hi + span));
      }
      span = hi - lo;
      if (span < this.minSpan) {
        const mid = (hi + lo) / 2;
        lo = mid - this.minSpan / 2;
        hi = mid + this.minSpan / 2;
        span = this.minSpan;
      }
      return [lo - 0.06 * span, hi + 0.06 * span];
    }
    firstTime() {
      let t = Infinity;
      for (const s of this.series) if (s.ring.length) t = Math.min(t, s.ring.t[s.ring.index(0)]);
      return t;
    }
    legendLayout(ctx, x0, xMax) {
      // entries of series that have data, wrapped onto lines after the title
      const items = [];
      let x = x0, line = 0;
      for (const s of this.series) {
        if (!s.legend || !s.ring.length) continue;
        const w = ctx.measureText(s.label).width + 30;
        if (x + w > xMax && x > x0) { line++; x = 52; }
        items.push({ s, x, line });
        x += w;
      }
      return { items, lines: line + 1 };
    }
    draw() {
      if (!this.resize()) return false;
      const ctx = this.ctx, W = this.cssWidth, H = this.cssHeight;
      const left = 52, right = 8, bottom = 20;
      ctx.font = TITLE_FONT;
      const title = this.unit ? `${this.title} [${this.unit}]` : this.title;
      const titleWidth = ctx.measureText(title).width;
      ctx.font = FONT;
      const legend = this.legendLayout(ctx, left + titleWidth + 24, W - right);
      const top = 22 + 15 * (legend.lines - 1);
      const pw = W - left - right, ph = H - top - bottom;
      // the window fills from the left until it is full, then scrolls
      const first = this.firstTime();
      const t1 = Math.max(this.now, (isFinite(first) ? first : 0) + this.window);
      const t0 = t1 - this.window;
      if (this.period) this.center = this.circularCenter(t0, t1);
      const [y0, y1] = this.yRange(t0, t1);
      const X = (t) => left + (t - t0) / (t1 - t0) * pw;
      const Y = (v) => top + (1 - (v - y0) / (y1 - y0)) * ph;

      ctx.clearRect(0, 0, W, H);
      ctx.fillStyle = "#ffffff";
      ctx.fillRect(left, top, pw, ph);
      // grid and tick labels
      ctx.font = FONT;
      ctx.lineWidth = 1;
      ctx.strokeStyle = "#e6e9ee";
      ctx.fillStyle = "#5b6573";
      ctx.textAlign = "right";
      ctx.textBaseline = "middle";
      const ys = niceStep(y1 - y0, Math.max(2, Math.floor(ph / 28)));
      ctx.beginPath();
      for (let v = Math.ceil(y0 / ys) * ys; v <= y1; v += ys) {
        const y = Math.round(Y(v)) + 0.5;
        ctx.moveTo(left, y); ctx.lineTo(left + pw, y);
        const label = this.tickLabel(v);
        ctx.fillText(fmt(Math.abs(label) < ys * 1e-6 ? 0 : label, ys), left - 5, y);
      }
      const xs = niceStep(this.window, Math.max(2, Math.floor(pw / 70)));
      ctx.textAlign = "center";
      ctx.textBaseline = "top";
      for (let t = Math.ceil(t0 / xs) * xs; t <= t1; t += xs) {
        const x = Math.round(X(t)) + 0.5;
        ctx.moveTo(x, top); ctx.lineTo(x, top + ph);
        if (t >= 0) {
          const label = fmt(t, xs) + (t + xs > t1 ? " s" : "");
          const half = ctx.measureText(label).width / 2;
          ctx.fillText(label, Math.min(x, W - right - half), top + ph + 4);  // keep the last one inside
        }
      }
      ctx.stroke();
      ctx.strokeStyle = "#b8c0cc";
      ctx.strokeRect(left + 0.5, top + 0.5, pw - 1, ph - 1);

      // series, clipped to the plot area
      ctx.save();
      ctx.beginPath();
      ctx.rect(left, top, pw, ph);
      ctx.clip();
      this.breaks = 0;
      for (const s of this.series) this.drawSeries(s, t0, t1, X, Y);
      ctx.restore();
      this.view = { t0, t1, y0, y1, center: this.center, breaks: this.breaks };

      // title (with unit) and legend
      ctx.textBaseline = "alphabetic";
      ctx.textAlign = "left";
      ctx.font = TITLE_FONT;
      ctx.fillStyle = "#1d2430";
      ctx.fillText(title, left, 15);
      ctx.font = FONT;
      for (const { s, x, line } of legend.items) {
        const yb = 15 + 15 * line;
        if (s.kind === "band") {
          ctx.fillStyle = s.fill;
          ctx.fillRect(x, yb - 8, 14, 9);
        } else if (s.kind === "dots") {
          ctx.fillStyle = s.color;
          ctx.fillRect(x + 5, yb - 6, 4, 4);
        } else {
          ctx.strokeStyle = s.color;
          ctx.lineWidth = 2;
          ctx.setLineDash(s.dash || []);
          ctx.beginPath(); ctx.moveTo(x, yb - 3.5); ctx.lineTo(x + 14, yb - 3.5); ctx.stroke();
          ctx.setLineDash([]);
        }
        ctx.fillStyle = "#3a4350";
        ctx.fillText(s.label, x + 18, yb);
      }
      this.dirty = false;
      return true;
    }
    drawSeries(s, t0, t1, X, Y) {
      const ctx = this.ctx, r = s.ring, P = this.period;
      if (!r.length) return;
      const k0 = Math.max(0, r.lowerBound(t0) - 1);
      if (s.kind === "band") {
        // one polygon per stretch without a wrap of its (unwrapped) middle
        ctx.fillStyle = s.fill;
        let idx = [], prevM = NaN;
        const fill = () => {
          if (!idx.length) return;
          ctx.beginPath();
          for (let j = 0; j < idx.length; j++) {
            const [x, , hi] = idx[j];
            if (j === 0) ctx.moveTo(x, Y(hi)); else ctx.lineTo(x, Y(hi));
          }
          for (let j = idx.length - 1; j >= 0; j--) ctx.lineTo(idx[j][0], Y(idx[j][1]));
          ctx.closePath();
          ctx.fill();
          idx = [];
        };
        for (let k = k0; k < r.length; k++) {
          const i = r.index(k);
          const a = r.v[2 * i], b = r.v[2 * i + 1], m = this.unwrap(0.5 * (a + b)), h = 0.5 * (b - a);
          if (P && Math.abs(m - prevM) > P / 2) { fill(); this.breaks++; }
          idx.push([X(r.t[i]), m - h, m + h]);
          prevM = m;
        }
        fill();
        return;
      }
      if (s.kind === "dots") {
        ctx.fillStyle = s.color;
        for (let k = k0; k < r.length; k++) {
          const i = r.index(k);
          ctx.fillRect(X(r.t[i]) - 1.25, Y(this.unwrap(r.v[i])) - 1.25, 2.5, 2.5);
        }
        return;
      }
      ctx.strokeStyle = s.color;
      ctx.lineWidth = s.width;
      ctx.lineJoin = "round";
      ctx.setLineDash(s.dash || []);
      ctx.beginPath();
      let prevT = NaN, prevV = NaN;
      for (let k = k0; k < r.length; k++) {
        const i = r.index(k);
        const t = r.t[i], v = this.unwrap(r.v[i]), x = X(t);
        if (isNaN(prevT) || t < prevT) ctx.moveTo(x, Y(v));
        else if (P && Math.abs(v - prevV) > P / 2) {
          // the angle passed the far side of the centre: leave at one edge, come back at the other
          this.breaks++;
          const shift = P * Math.round((v - prevV) / P); // v - shift is the continuation of prevV
          if (s.kind === "step") { ctx.lineTo(x, Y(prevV)); ctx.moveTo(x, Y(v)); }
          else { ctx.lineTo(x, Y(v - shift)); ctx.moveTo(X(prevT), Y(prevV + shift)); ctx.lineTo(x, Y(v)); }
        }
        else if (s.kind === "step") { ctx.lineTo(x, Y(prevV)); ctx.lineTo(x, Y(v)); }
        else ctx.lineTo(x, Y(v));
        prevT = t;
        prevV = v;
      }
      if (s.kind === "step" && !isNaN(prevT)) ctx.lineTo(X(Math.max(prevT, this.now)), Y(prevV));
      ctx.stroke();
      ctx.setLineDash([]);
    }
  }

  // A TrackPlot shows the horizontal track seen from above (NED: north up, east to the right)
  // with equal scales on both axes: a few polylines (truth, estimate, reference) of the last
  // `capacity` points each, and markers for the current set-point. Same interface as StripChart
  // for the page: push(name, north, east), clear(), draw(), dirty.
  class TrackPlot {
    constructor(canvas, opts) {
      this.canvas = canvas;
      this.ctx = canvas.getContext("2d");
      this.title = opts.title || "";
      this.minSpan = opts.minSpan || 1.0;
      this.capacity = opts.capacity || 3000;
      this.series = [];
      this.byName = {};
      this.dirty = true;
      this.cssWidth = 0;
      this.cssHeight = 0;
      this.points = 0; // points drawn in the last draw (tests read it)
    }
    add(opts) {
      const s = { name: opts.name, label: opts.label || opts.name, color: opts.color || "#333",
                  width: opts.width || 1.5, dash: opts.dash || null, marker: !!opts.marker,
                  ring: new Ring(this.capacity, 2) };
      this.series.push(s);
      this.byName[s.name] = s;
      this.dirty = true;
      return s;
    }
    get(name) { return this.byName[name]; }
    push(name, north, east) {
      const s = this.byName[name];
      if (s === undefined || !isFinite(north) || !isFinite(east)) return;
      s.ring.push(s.ring.length, north, east);
      this.dirty = true;
    }
    clear() {
      for (const s of this.series) s.ring.clear();
      this.dirty = true;
    }
    resize() { return StripChart.prototype.resize.call(this); }
    draw() {
      if (!this.resize()) return false;
      const ctx = this.ctx, W = this.cssWidth, H = this.cssHeight;
      ctx.clearRect(0, 0, W, H);
      const pad = { l: 46, r: 10, t: 20, b: 30 };
      let nMin = Infinity, nMax = -Infinity, eMin = Infinity, eMax = -Infinity, count = 0;
      for (const s of this.series) {
        const r = s.ring;
        for (let k = 0; k < r.length; k++) {
          const i = r.index(k);
          const n = r.v[2 * i], e = r.v[2 * i + 1];
          if (n < nMin) nMin = n; if (n > nMax) nMax = n;
          if (e < eMin) eMin = e; if (e > eMax) eMax = e;
          count++;
        }
      }
      ctx.font = TITLE_FONT;
      ctx.fillStyle = "#222";
      ctx.fillText(this.title, pad.l, 13);
      this.points = count;
      if (count === 0) { this.dirty = false; return true; }
      const pw = W - pad.l - pad.r, ph = H - pad.t - pad.b;
      const span = Math.max(this.minSpan, (nMax - nMin) * 1.15, (eMax - eMin) * 1.15 * ph / Math.max(pw, 1));
      const scale = ph / span; // pixels per metre, the same on both axes
      const nMid = 0.5 * (nMin + nMax), eMid = 0.5 * (eMin + eMax);
      const X = (e) => pad.l + pw / 2 + (e - eMid) * scale;
      const Y = (n) => pad.t + ph / 2 - (n - nMid) * scale;
      // grid
      const step = niceStep(span, 5);
      ctx.strokeStyle = "#e3e3e3";
      ctx.lineWidth = 1;
      ctx.font = FONT;
      ctx.fillStyle = "#666";
      for (let n = Math.ceil((nMid - span / 2) / step) * step; n <= nMid + span / 2; n += step) {
        ctx.beginPath(); ctx.moveTo(pad.l, Y(n)); ctx.lineTo(W - pad.r, Y(n)); ctx.stroke();
        ctx.fillText(fmt(Math.abs(n) < 1e-9 * step ? 0 : n, step), 4, Y(n) + 4);
      }
      const eSpan = pw / scale;
      for (let e = Math.ceil((eMid - eSpan / 2) / step) * step; e <= eMid + eSpan / 2; e += step) {
        ctx.beginPath(); ctx.moveTo(X(e), pad.t); ctx.lineTo(X(e), H - pad.b); ctx.stroke();
        ctx.fillText(fmt(Math.abs(e) < 1e-9 * step ? 0 : e, step), X(e) - 8, H - pad.b + 13);
      }
      ctx.fillText("east [m] →", W - pad.r - 70, H - 4);
      ctx.save();
      ctx.translate(11, pad.t + ph / 2 + 30);
      ctx.rotate(-Math.PI / 2);
      ctx.fillText("north [m] →", 0, 0);
      ctx.restore();
      for (const s of this.series) {
        const r = s.ring;
        if (r.length === 0) continue;
        ctx.strokeStyle = s.color;
        ctx.fillStyle = s.color;
        ctx.lineWidth = s.width;
        ctx.setLineDash(s.dash || []);
        if (s.marker) {
          const i = r.index(r.length - 1);
          ctx.fillRect(X(r.v[2 * i + 1]) - 4, Y(r.v[2 * i]) - 4, 8, 8);
        } else {
          ctx.beginPath();
          for (let k = 0; k < r.length; k++) {
            const i = r.index(k);
            if (k === 0) ctx.moveTo(X(r.v[2 * i + 1]), Y(r.v[2 * i])); else ctx.lineTo(X(r.v[2 * i + 1]), Y(r.v[2 * i]));
          }
          ctx.stroke();
        }
        ctx.setLineDash([]);
      }
      this.dirty = false;
      return true;
    }
  }

  global.RovPlot = { StripChart, TrackPlot, niceStep, fmt };
})(window);
