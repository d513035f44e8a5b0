/* gen-config-doc — print the configuration reference (Markdown) from the one
 * parameter table, server/sim/params.c. scripts/gen-config-doc.sh splices it
 * between the <!-- config-reference --> markers of docs/configuration.md,
 * and tests/tap/ops.sh fails when they disagree. */
#include <stdio.h>
#include <string.h>

#include "params.h"

/* Table cells may not contain '|'. */
static void cell(const char *s)
{
    for (; *s; s++) {
        if (*s == '|') fputs("\\|", stdout);
        else if (*s == '\n') putchar(' ');
        else putchar(*s);
    }
}

static const char *type_name(enum param_type t)
{
    switch (t) {
    case PARAM_INT: return "int";
    case PARAM_FLOAT: return "float";
    case PARAM_ENUM: return "enum";
    case PARAM_BOOL: return "bool";
    case PARAM_STRING: return "string";
    }
    return "?";
}

/* Command-line spelling: underscores become dashes (--wind-speed). */
static void flag(const char *name)
{
    fputs("`--", stdout);
    for (; *name; name++) putchar(*name == '_' ? '-' : *name);
    putchar('`');
}

int main(void)
{
    puts("| parameter | flag | type | unit | allowed | default | description |");
    puts("|---|---|---|---|---|---|---|");
    for (size_t i = 0; i < param_count; i++) {
        const struct param_def *d = &param_table[i];
        printf("| `%s` | ", d->name);
        flag(d->name);
        printf(" | %s | %s | ", type_name(d->type), d->unit && *d->unit ? d->unit : "–");
        switch (d->type) {
        case PARAM_ENUM:
            for (int k = 0; d->choices && d->choices[k]; k++) printf("%s`%s`", k ? ", " : "", d->choices[k]);
            printf(" | `%s` | ", param_enum_name(d, (int)d->def));
            break;
        case PARAM_BOOL:
            printf("`true`, `false` | `%s` | ", d->def != 0 ? "true" : "false");
            break;
        default:
            printf("%s%.10g … %.10g | %.10g | ", (d->flags & PARAM_POW2) ? "power of two, " : "", d->min, d->max, d->def);
            break;
        }
        cell(d->description ? d->description : "");
        puts(" |");
    }
    return 0;
}
