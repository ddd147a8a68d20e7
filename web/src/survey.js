// The survey plot: sensor positions from above (x-y) and from the side (x-z), and a few pings'
// envelopes, from GET /reconstructions/{id}/survey (the summary `shsas info` prints).

function axes(ctx, x0, y0, w, h, title) {
  ctx.strokeStyle = "#c8ced6";
  ctx.strokeRect(x0, y0, w, h);
  ctx.fillStyle = "#333";
  ctx.font = "12px system-ui, sans-serif";
  ctx.fillText(title, x0 + 4, y0 + 14);
}

function scatter(ctx, pts, [i, j], x0, y0, w, h, colour, bounds) {
  const [lo, hi] = bounds;
  const span = Math.max(hi[i] - lo[i], hi[j] - lo[j]) || 1;
  const s = (Math.min(w, h) - 30) / span;
  const cx = x0 + w / 2 - ((lo[i] + hi[i]) / 2) * s;
  const cy = y0 + h / 2 + ((lo[j] + hi[j]) / 2) * s + 8;
  ctx.fillStyle = colour;
  for (const p of pts) ctx.fillRect(cx + p[i] * s - 1.5, cy - p[j] * s - 1.5, 3, 3);
}

function bounds(...sets) {
  const lo = [Infinity, Infinity, Infinity];
  const hi = [-Infinity, -Infinity, -Infinity];
  for (const pts of sets) for (const p of pts) for (let k = 0; k < 3; k++) {
    lo[k] = Math.min(lo[k], p[k]);
    hi[k] = Math.max(hi[k], p[k]);
  }
  return [lo, hi];
}

export function plotSurvey(canvas, view) {
  const ctx = canvas.getContext("2d");
  const { width: W, height: H } = canvas;
  ctx.clearRect(0, 0, W, H);
  const box = view.summary.scene_box_m;
  const b = bounds(view.tx, view.rx, [box.min, box.max]);
  const half = W / 2 - 6;
  axes(ctx, 4, 4, half, H - 8, "from above (x–y)");
  axes(ctx, W / 2 + 2, 4, half, H - 8, "from the side (x–z)");
  for (const [plane, x0] of [[[0, 1], 4], [[0, 2], W / 2 + 2]]) {
    scatter(ctx, [box.min, box.max], plane, x0, 4, half, H - 8, "#999", b);
    scatter(ctx, view.rx, plane, x0, 4, half, H - 8, "#e0a34f", b);
    scatter(ctx, view.tx, plane, x0, 4, half, H - 8, "#0b5cad", b);
  }
  ctx.fillStyle = "#0b5cad";
  ctx.fillText("■ tx", 10, H - 14);
  ctx.fillStyle = "#e0a34f";
  ctx.fillText("■ rx", 44, H - 14);
  ctx.fillStyle = "#999";
  ctx.fillText("■ scene box corners", 78, H - 14);
}

export function plotPings(canvas, view) {
  const ctx = canvas.getContext("2d");
  const { width: W, height: H } = canvas;
  ctx.clearRect(0, 0, W, H);
  axes(ctx, 4, 4, W - 8, H - 8, view.pings.length ? "ping envelopes |s(t)| (normalised), time after transmit" : "pings not shown for this input");
  if (!view.pings.length) return;
  const t0 = Math.min(...view.pings.map((p) => p.t0_s));
  const t1 = Math.max(...view.pings.map((p) => p.t0_s + p.dt_s * p.envelope.length));
  const colours = ["#0b5cad", "#b3261e", "#1e7b34", "#8a5a00"];
  view.pings.forEach((p, k) => {
    const peak = Math.max(...p.envelope) || 1;
    ctx.strokeStyle = colours[k % colours.length];
    ctx.beginPath();
    p.envelope.forEach((v, n) => {
      const x = 10 + ((p.t0_s + n * p.dt_s - t0) / (t1 - t0 || 1)) * (W - 20);
      const y = H - 10 - (v / peak) * (H - 40);
      n ? ctx.lineTo(x, y) : ctx.moveTo(x, y);
    });
    ctx.stroke();
    ctx.fillStyle = ctx.strokeStyle;
    ctx.fillText(`ping ${p.index}`, W - 80, 20 + 14 * k);
  });
  ctx.fillStyle = "#333";
  ctx.fillText(`${(t0 * 1e3).toFixed(2)} ms`, 10, H - 12);
  ctx.fillText(`${(t1 * 1e3).toFixed(2)} ms`, W - 70, H - 12);
}
