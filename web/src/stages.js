// Plain names for the pipeline's stage keys ("fit:shsas", "warm start:reed", ...), which are
// internal names; an unknown key is shown as it is.

const METHOD = { backprojection: "backprojection", reed: "Reed et al. (SH degree 0)", shsas: "SH-SAS" };
const STAGE = {
  load: "reading the survey",
  deconvolution: "pulse deconvolution",
  report: "writing the report",
  done: "finishing",
  queued: "waiting for a worker",
  autofocus: "estimating the sound speed and track (autofocus)",
  simulate: "simulating the survey",
};

export function plainStage(stage) {
  if (!stage) return "";
  if (STAGE[stage]) return STAGE[stage];
  if (METHOD[stage]) return `imaging with ${METHOD[stage]}`;
  const [kind, method] = stage.split(":");
  const name = METHOD[method] || method;
  if (kind === "fit") return `training ${name}`;
  if (kind === "warm start") return `starting ${name} from the backprojection image`;
  if (kind === "import") return "reading the survey";
  return stage;
}

export const methodName = (m) => METHOD[m] || m;
