// What a user can act on, as core/errors.py: a bad value is an InputError
// with a one-line message, naming its field where there is one; values that
// do not go together are a ConflictError naming them all.

/** Bad input (a file refused, a value out of range): its message is one line for the user. */
export class InputError extends Error {
  constructor(message, field = null) {
    super(message);
    this.field = field;
  }
}

/** Fields given together that cannot be (or one without another it needs): `fields` lists them all. */
export class ConflictError extends InputError {
  constructor(message, fields) {
    super(message);
    this.fields = fields;
  }
}

/** A value as Python's repr() writes it: messages say what was given in the Python runtime's words. */
export function pyRepr(value) {
  if (value === null || value === undefined) return 'None';
  if (typeof value === 'boolean') return value ? 'True' : 'False';
  if (typeof value === 'string') {
    const quote = value.includes("'") && !value.includes('"') ? '"' : "'";
    return quote + value.replaceAll('\\', '\\\\').replaceAll(quote, `\\${quote}`) + quote;
  }
  if (typeof value === 'number' && !Number.isFinite(value)) return Number.isNaN(value) ? 'nan' : value > 0 ? 'inf' : '-inf';
  if (Array.isArray(value)) return `[${value.map(pyRepr).join(', ')}]`;
  return String(value);
}

/** An array as Python writes a tuple, (2, 3) or (2,) (a shape in a message); anything else as repr(). */
export const pyTuple = (value) => (Array.isArray(value) ? `(${value.map(pyRepr).join(', ')}${value.length === 1 ? ',' : ''})` : pyRepr(value));

/** A value as Python's str() writes it (a string as it is). */
export const pyStr = (value) => (typeof value === 'string' ? value : pyRepr(value));

/** A number as Python's '{:g}' writes it: 6 significant digits, an exponent of two digits or more. */
export function formatG(value) {
  const v = Number(value.toPrecision(6));
  const exponent = v === 0 ? 0 : Math.floor(Math.log10(Math.abs(v)));
  if (!Number.isFinite(v) || (exponent >= -4 && exponent < 6)) return pyRepr(v);
  return v.toExponential().replace(/e([+-])(\d)$/, 'e$10$2');
}
