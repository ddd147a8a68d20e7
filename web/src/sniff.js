// What kind of file a survey is, from its first bytes, as the server's format detection reads
// them (shsas_core.formats.detect_format): HDF5 (canonical, SVSS), zip (AirSAS CSV), pickle
// (AirSAS processed). A file that is none of them is refused before its upload starts.

const HDF5 = [0x89, 0x48, 0x44, 0x46, 0x0d, 0x0a, 0x1a, 0x0a];
const PICKLE_NAMES = /\.(pkl|pik|pickle)$/i;

function startsWith(bytes, sig, at = 0) {
  return sig.every((b, i) => bytes[at + i] === b);
}

/** Null when ``file`` can be a survey, else the message naming the problem and its fix. */
export async function sniffSurvey(file) {
  if (file.size === 0) return `survey '${file.name}': the file is empty (fix: check that this is the survey file)`;
  const head = new Uint8Array(await file.slice(0, 8).arrayBuffer());
  if (startsWith(head, HDF5)) return null;
  if (startsWith(head, [0x50, 0x4b, 0x03, 0x04]) || startsWith(head, [0x50, 0x4b, 0x05, 0x06])) return null;
  if (head[0] === 0x80 || PICKLE_NAMES.test(file.name)) return null;
  return `survey '${file.name}': not a recognised survey — its first bytes are not HDF5, zip or a pickle ` +
    "(expected canonical HDF5, an AirSAS .zip, an AirSAS processed pickle, or SVSS HDF5) " +
    "(fix: check that this is the survey file; nothing was uploaded)";
}
